#!/usr/bin/env python3
"""Plots and summarises the two soaks `scripts/soak.sh` runs (the CSVs of `glintd soak`).

Writes the plot (resident memory, per-sweep CPU time and latency against sensor time, SLAM and
localisation side by side) and a Markdown report with the figures the soak is judged by:
  - every sweep processed, no panic (from the logs);
  - per-sweep CPU time flat: the last hour's median against the first hour's;
  - localisation: RSS flat, the last hour's mean against the first hour's (after the first
    ten minutes of start-up, in which the local maps and the services' shared memory fill);
  - SLAM: RSS growth per metre driven, fitted past the start-up, against the back end's
    memory per metre on a route it keeps revisiting (docs/backend.md).
"""
import argparse
import csv
import re
import subprocess
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

START_UP_S = 600.0
HOUR_S = 3600.0


def load(path):
    with open(path, newline="") as f:
        rows = [{k: float(v) for k, v in r.items()} for r in csv.DictReader(f)]
    if len(rows) < 2:
        sys.exit(f"{path}: fewer than two samples")
    return rows


def median(values):
    v = sorted(values)
    if not v:
        return float("nan")
    n = len(v)
    return v[n // 2] if n % 2 else 0.5 * (v[n // 2 - 1] + v[n // 2])


def mean(values):
    return sum(values) / len(values) if values else float("nan")


def first_and_last_hour(rows, key):
    """The column's samples in the first hour past the start-up and in the last hour."""
    end = rows[-1]["sensor_s"]
    first = [r[key] for r in rows if START_UP_S <= r["sensor_s"] < START_UP_S + HOUR_S]
    last = [r[key] for r in rows if r["sensor_s"] >= end - HOUR_S]
    return first, last


def slope(xs, ys):
    """Least-squares slope of ys on xs."""
    mx, my = mean(xs), mean(ys)
    sxx = sum((x - mx) ** 2 for x in xs)
    return sum((x - mx) * (y - my) for x, y in zip(xs, ys)) / sxx if sxx > 0 else float("nan")


def log_facts(path):
    text = open(path, errors="replace").read()
    done = re.search(r"soak done: (\d+) sweeps in (\d+) s \((\d+) initialising, (\d+) tracking, "
                     r"(\d+) degenerate, (\d+) lost\); peak RSS ([\d.]+) MiB", text)
    return {
        "panics": text.count("panicked"),
        "done": done.groups() if done else None,
        "backend": (re.search(r"back end: (.*)", text) or [None, ""])[1],
        "localisation": (re.search(r"localisation: (.*)", text) or [None, ""])[1],
    }


def commit():
    try:
        return subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True,
                              text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--slam", required=True)
    ap.add_argument("--localisation", required=True)
    ap.add_argument("--slam-log", required=True)
    ap.add_argument("--localisation-log", required=True)
    ap.add_argument("--plot", required=True)
    ap.add_argument("--report", help="also write the figures as a Markdown page here")
    ap.add_argument("--command", default="bash scripts/soak.sh",
                    help="the command that produced the CSVs, for the report")
    ap.add_argument("--commit", help="the commit the soaks ran (default: the checkout's)")
    args = ap.parse_args()
    runs = {"SLAM": (load(args.slam), log_facts(args.slam_log)),
            "localisation": (load(args.localisation), log_facts(args.localisation_log))}

    fig, axes = plt.subplots(3, 1, figsize=(10, 10), sharex=True)
    for name, (rows, _) in runs.items():
        h = [r["sensor_s"] / HOUR_S for r in rows]
        axes[0].plot(h, [r["rss_mib"] for r in rows], label=name)
        axes[1].plot(h, [r["cpu_ms_per_sweep"] for r in rows], label=f"{name}: CPU per sweep")
        axes[1].plot(h, [r["compute_median_ms"] for r in rows], linestyle=":",
                     label=f"{name}: front end + odometry (wall, median)")
        axes[2].plot(h, [r["latency_median_ms"] for r in rows], label=f"{name}: median")
        axes[2].plot(h, [r["latency_p99_ms"] for r in rows], linestyle=":", label=f"{name}: p99")
    axes[0].set_ylabel("resident memory (MiB)")
    axes[1].set_ylabel("ms per sweep")
    axes[2].set_ylabel("sweep closed → pose published (ms)")
    axes[2].set_xlabel("sensor time (h)")
    for ax in axes:
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=8)
        ax.set_ylim(bottom=0)
    fig.suptitle("glintd soak: simulated warehouse at the stages' own pace, one sample a minute")
    fig.tight_layout()
    fig.savefig(args.plot, dpi=110)

    out = [f"Commit {args.commit or commit()}; `{args.command}`; written by `scripts/soak_plot.py`.", "",
           "| | SLAM | localisation |", "|---|---|---|"]

    def row(label, f):
        out.append(f"| {label} | " + " | ".join(f(*runs[k]) for k in ("SLAM", "localisation")) + " |")

    def done(facts, i):
        return facts["done"][i] if facts["done"] else "—"

    row("sweeps processed", lambda rows, facts: done(facts, 0))
    row("sensor time (h)", lambda rows, facts: f"{rows[-1]['sensor_s'] / HOUR_S:.2f}")
    row("wall time (min)", lambda rows, facts: f"{rows[-1]['wall_s'] / 60:.0f}")
    row("distance driven (km)", lambda rows, facts: f"{rows[-1]['distance_m'] / 1e3:.1f}")
    row("panics", lambda rows, facts: str(facts["panics"]))
    row("sweeps lost (odometry)", lambda rows, facts: done(facts, 5))
    row("peak RSS (MiB)", lambda rows, facts: done(facts, 6))

    def ratio(rows, key, agg):
        first, last = first_and_last_hour(rows, key)
        return agg(first), agg(last), agg(last) / agg(first)

    def cpu(rows, facts):
        a, b, r = ratio(rows, "cpu_ms_per_sweep", median)
        return f"{a:.2f} → {b:.2f} (×{r:.3f})"

    def rss(rows, facts):
        a, b, r = ratio(rows, "rss_mib", mean)
        return f"{a:.1f} → {b:.1f} (×{r:.3f})"

    def latency(rows, facts):
        a, b, r = ratio(rows, "latency_median_ms", median)
        return f"{a:.2f} → {b:.2f} (×{r:.3f})"

    row("CPU per sweep, first → last hour, median (ms)", cpu)
    row("latency, first → last hour, median (ms)", latency)
    row("RSS, first → last hour, mean (MiB)", rss)

    def growth(rows, facts):
        past = [r for r in rows if r["sensor_s"] >= START_UP_S]
        s = slope([r["distance_m"] for r in past], [r["rss_mib"] * 1048576 for r in past])
        return f"{s / 1e3:.2f} kB/m"

    row("RSS growth per metre driven (fit past the start-up)", growth)
    loc = runs["localisation"][1]["localisation"]
    slam = runs["SLAM"][1]["backend"]
    out += ["", f"SLAM back end: {slam or '—'}", "", f"Localisation: {loc or '—'}", ""]
    print("\n".join(out))
    if args.report:
        import os
        image = os.path.relpath(args.plot, os.path.dirname(os.path.abspath(args.report)))
        head = ["# Soak: hours of data without a restart", "",
                "Generated by `scripts/soak.sh` (do not edit by hand). `glintd soak` feeds a "
                "simulated VLP-16, run in process, through the whole pipeline at the stages' own "
                "pace: once mapping (SLAM) and once localising in a map of the same site, made "
                "from two laps beforehand. Each row of the CSVs is one wall-clock minute; the "
                "first ten minutes of sensor time are start-up (the local maps and the services' "
                "shared memory fill) and "
                "are left out of the first-hour figures. *CPU per sweep* is the CPU time of "
                "every pipeline thread (front end, odometry, back end or localiser, publishing) "
                "but the simulated sensor's, so other work on the machine changes it only through "
                "the cores and caches it shares; latency and wall-clock compute include waiting "
                "for a core. Both run with the environment `systemd/glintd.service` gives the "
                "daemon (`Environment=`: glibc's fixed malloc thresholds).", "",
                f"![soak]({image})", ""]
        with open(args.report, "w") as f:
            f.write("\n".join(head + out))


if __name__ == "__main__":
    main()
