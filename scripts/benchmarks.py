#!/usr/bin/env python3
"""Runs Glint's benchmarks and writes docs/benchmarks.md from what they print.

    python3 scripts/benchmarks.py            # everything (long: the better part of an hour on 2 cores)
    python3 scripts/benchmarks.py --quick    # short runs, a few minutes; no peers, memory or latency
    python3 scripts/benchmarks.py --glintd target/release/glintd --no-peers

Every figure in the page comes from a command this script runs, and the page shows the command:
nothing is copied by hand, so the page is only ever as old as its header says. It runs
  1. odometry accuracy: `glintd sim` on the standard scenarios and seeds, then
     `glintd replay D/scan.pcap --groundtruth D/groundtruth.tum --no-publish --no-loop`
     (and `--no-intensity` on one seed per scenario, the geometry-only ablation);
  2. SLAM accuracy: the same replay with the back end (no `--no-loop`) on long runs;
  3. odometry time on one core: `taskset -c 0 glintd bench D/scan.pcap` (median of --repeat runs);
  4. the whole chain: `glintd demo`; the pose graph: `glintd posegraph` on the parking garage;
  5. latency at the sensor's pace: `glintd replay D/scan.pcap --pace realtime`;
  6. `scripts/localisation_bench.py` (localisation in a saved map, 20 runs; 4 with --quick),
  7. `scripts/compare_peers.py` (KISS-ICP on the same sweeps; needs PyPI) and
     `scripts/memory_bench.py` (peak RSS, odometry and `--slam`), when present.
--quick shortens 1-4 and 6 and leaves out 5 and 7. Simulated runs go to target/benchmarks/ (reused when the
same scenario, seed and length is asked again). Plain Python 3, no packages.
"""
import argparse
import datetime
import os
import platform
import re
import shutil
import statistics
import subprocess
import sys

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
DOC = os.path.join(REPO, "docs", "benchmarks.md")
SHARED = os.path.join(os.path.dirname(REPO), "shared")

# (scenario, seed, seconds): the runs the odometry's drift figures are quoted over.
ODOMETRY_RUNS = [("warehouse", 3, 60), ("yard", 7, 60), ("yard", 19, 60),
                 ("yard", 2, 160), ("yard", 8, 160), ("yard", 11, 160),
                 ("corridor", 5, 60), ("corridor", 8, 60), ("corridor", 14, 60)]
# Geometry only on one seed per scenario: the ablation that shows what intensity holds.
GEOMETRY_RUNS = [("warehouse", 3, 60), ("yard", 7, 60), ("corridor", 5, 60)]
# Long runs for SLAM: a lap and a sixth of the yard, two laps and a half of the warehouse.
SLAM_RUNS = [("yard", 2, 160), ("yard", 8, 160), ("yard", 11, 160), ("yard", 23, 160),
             ("yard", 37, 160), ("yard", 41, 160), ("warehouse", 5, 200),
             ("warehouse", 17, 200)]
BENCH_RUNS = [("warehouse", 3, 60), ("yard", 7, 60), ("corridor", 5, 60)]

QUICK_SECONDS = 20
QUICK_ODOMETRY = [("warehouse", 3, QUICK_SECONDS), ("yard", 7, QUICK_SECONDS),
                  ("corridor", 5, QUICK_SECONDS)]
QUICK_SLAM = [("warehouse", 3, QUICK_SECONDS), ("yard", 7, QUICK_SECONDS)]


class Failure(Exception):
    """A command failed; the message names it and the tail of its output."""


def run(cmd, cwd=REPO):
    """Runs cmd, echoing it; returns its output (stdout and stderr together)."""
    print("  $ " + shown(cmd), flush=True)
    proc = subprocess.run(cmd, cwd=cwd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                          universal_newlines=True)
    if proc.returncode != 0:
        tail = "\n".join(proc.stdout.strip().splitlines()[-15:])
        raise Failure(f"status {proc.returncode}: {shown(cmd)}\n{tail}")
    return proc.stdout


def shown(cmd):
    """A command as the page shows it: paths relative to the repository."""
    out = []
    for c in cmd:
        c = str(c)
        if c.startswith(REPO + os.sep):
            c = os.path.relpath(c, REPO)
        elif c.startswith(SHARED + os.sep):
            c = "../shared/" + os.path.relpath(c, SHARED)
        out.append(c)
    return " ".join(out)


def number(pattern, text, default=None):
    m = re.search(pattern, text, re.M)
    return float(m.group(1)) if m else default


def accuracy(text, prefix=""):
    """Drift (%), drift (°/m), ATE RMSE (m), return to start (m) from replay's printout."""
    p = re.escape(prefix)
    return {
        "drift": number(rf"^{p}drift ([0-9.]+) %", text),
        "drift_deg": number(rf"^{p}drift [0-9.]+ % / ([0-9.]+) °/m", text),
        "ate": number(rf"^{p}ATE RMSE ([0-9.]+) m", text),
        "rts": number(rf"^{p}return to start: ([0-9.]+) m", text),
    }


def timing(text):
    """Per-sweep and per-stage median / p99 (ms) from replay's or bench's printout."""
    t = {}
    for key, label in (("sweep", "per sweep"),
                       ("features", "calibration \\+ features(?: after the last packet)?"),
                       ("alignment", "alignment"), ("map", "map update")):
        m = re.search(rf"^\s*{label}: median ([0-9.]+) ms, p99 ([0-9.]+) ms", text, re.M)
        t[key] = (float(m.group(1)), float(m.group(2))) if m else (None, None)
    m = re.search(r"^latency \(sweep received → pose published\): median ([0-9.]+) ms, "
                  r"p99 ([0-9.]+) ms", text, re.M)
    t["latency"] = (float(m.group(1)), float(m.group(2))) if m else (None, None)
    return t


def fmt(x, digits=3, unit=""):
    return "—" if x is None else f"{x:.{digits}f}{unit}"


class Bench:
    def __init__(self, glintd, out, quick):
        self.glintd = glintd
        self.out = out
        self.quick = quick
        self.sections = []

    def simulate(self, scenario, seed, seconds):
        d = os.path.join(self.out, f"{scenario}-s{seed}-{seconds:g}s")
        if not os.path.exists(os.path.join(d, "groundtruth.tum")):
            run([self.glintd, "sim", scenario, "--seed", str(seed), "--seconds", f"{seconds:g}",
                 "--out", d])
        return d

    def replay(self, d, *flags):
        name = "est" + "".join(f.replace("--", "_").replace("-", "_") for f in flags) + ".tum"
        return run([self.glintd, "replay", os.path.join(d, "scan.pcap"), "--trajectory",
                    os.path.join(d, name), "--groundtruth", os.path.join(d, "groundtruth.tum"),
                    "--no-publish", *flags])

    def section(self, title, intro, command, table):
        self.sections.append(f"## {title}\n\n{intro}\n\n```sh\n{command}\n```\n\n{table}\n")

    def odometry(self):
        runs = QUICK_ODOMETRY if self.quick else ODOMETRY_RUNS
        geometry = QUICK_ODOMETRY if self.quick else GEOMETRY_RUNS
        rows = ["| run | drift | ATE RMSE | return to start | per sweep, median / p99 "
                "(pipeline) | geometry only: drift / ATE |",
                "| --- | --- | --- | --- | --- | --- |"]
        drifts = []
        for scenario, seed, seconds in runs:
            d = self.simulate(scenario, seed, seconds)
            text = self.replay(d, "--no-loop")
            a, t = accuracy(text), timing(text)
            drifts.append(a["drift"])
            geo = "—"
            if (scenario, seed, seconds) in geometry:
                g = accuracy(self.replay(d, "--no-loop", "--no-intensity"))
                geo = f"{fmt(g['drift'])} % / {fmt(g['ate'])} m"
            rows.append(f"| {scenario} {seed}, {seconds:g} s | {fmt(a['drift'])} % "
                        f"({fmt(a['drift_deg'], 4)} °/m) | {fmt(a['ate'])} m | "
                        f"{fmt(a['rts'])} m | {fmt(t['sweep'][0], 1)} / "
                        f"{fmt(t['sweep'][1], 1)} ms | {geo} |")
        valid = [x for x in drifts if x is not None]
        mean = f"\n\nMean drift with intensity: {statistics.mean(valid):.3f} %." if valid else ""
        self.section(
            "Odometry accuracy",
            "Drift KITTI style over 5–50 m segments (shorter runs fit only the shorter segments), "
            "ATE RMSE after SE(3) alignment, return to start where the truth comes back to its "
            "start. Targets: drift ≤ 0.5 % (corridor ≤ 1 %). Times are the pipeline's (front end "
            "and odometry on two threads, replay at full speed).",
            "glintd sim SCENARIO --seed N --seconds S --out D\n"
            "glintd replay D/scan.pcap --trajectory D/est.tum --groundtruth D/groundtruth.tum "
            "--no-publish --no-loop [--no-intensity]",
            "\n".join(rows) + mean)

    def slam(self):
        runs = QUICK_SLAM if self.quick else SLAM_RUNS
        rows = ["| run | ATE, odometry → SLAM | return to start, odometry → SLAM | keyframes | "
                "loops found / verified / accepted |", "| --- | --- | --- | --- | --- |"]
        for scenario, seed, seconds in runs:
            d = self.simulate(scenario, seed, seconds)
            text = self.replay(d)
            o, s = accuracy(text, "odometry: "), accuracy(text, "SLAM: ")
            m = re.search(r"back end: (\d+) keyframes; loops found (\d+), verified (\d+), "
                          r"accepted (\d+)", text)
            kf, loops = (m.group(1), "/".join(m.group(2, 3, 4))) if m else ("—", "—")
            rows.append(f"| {scenario} {seed}, {seconds:g} s | {fmt(o['ate'])} → "
                        f"{fmt(s['ate'])} m | {fmt(o['rts'])} → {fmt(s['rts'])} m | {kf} | "
                        f"{loops} |")
        self.section(
            "SLAM accuracy",
            "The same replay with the back end (keyframes, loops, floor edges); it prints the "
            "odometry's and SLAM's figures side by side.",
            "glintd replay D/scan.pcap --trajectory D/est.tum --groundtruth D/groundtruth.tum "
            "--no-publish",
            "\n".join(rows))

    def bench(self, repeat):
        pin = ["taskset", "-c", "0"] if shutil.which("taskset") else []
        rows = ["| run | per sweep, median / p99 | calibration + features after the last packet "
                "| alignment | "
                "map update |", "| --- | --- | --- | --- | --- |"]
        runs = QUICK_ODOMETRY if self.quick else BENCH_RUNS
        for scenario, seed, seconds in runs:
            d = self.simulate(scenario, seed, seconds)
            ts = [timing(run(pin + [self.glintd, "bench", os.path.join(d, "scan.pcap")]))
                  for _ in range(repeat)]

            def med(key, i):
                v = [t[key][i] for t in ts if t[key][i] is not None]
                return statistics.median(v) if v else None
            rows.append(f"| {scenario} {seed}, {seconds:g} s | {fmt(med('sweep', 0), 1)} / "
                        f"{fmt(med('sweep', 1), 1)} ms | {fmt(med('features', 0), 1)} ms | "
                        f"{fmt(med('alignment', 0), 1)} ms | {fmt(med('map', 0), 1)} ms |")
        self.section(
            "Odometry time on one core",
            f"The odometry alone on one thread, decoding untimed; median of {repeat} run(s) of "
            "each figure. Targets: median ≤ 10 ms, p99 ≤ 25 ms per sweep."
            + ("" if pin else " (`taskset` was not found: the runs were not pinned.)"),
            ("taskset -c 0 " if pin else "") + "glintd bench D/scan.pcap",
            "\n".join(rows))

    def demo(self):
        seconds = QUICK_SECONDS if self.quick else 80
        d = os.path.join(self.out, "demo")
        text = run([self.glintd, "demo", "--out", d, "--seconds", str(seconds), "--domain",
                    f"bench{os.getpid()}"])
        keep = [line for line in text.splitlines()
                if re.match(r"^(sweeps|per sweep|  \w|latency|back end|odometry|SLAM)", line)]
        self.section(
            "The whole chain",
            "`glintd demo`: a simulated warehouse (seed 1) through the driver, front end, "
            "odometry and back end, publishing on iceoryx2. At full speed the latency includes "
            "the time a sweep waits behind the ones read ahead of it.",
            f"glintd demo --seconds {seconds}",
            "```\n" + "\n".join(keep) + "\n```")

    def posegraph(self):
        g2o = os.path.join(SHARED, "data", "parking-garage.g2o")
        if not os.path.exists(g2o):
            print("  (no ../shared/data/parking-garage.g2o: pose graph skipped)")
            return
        text = run([self.glintd, "posegraph", g2o, "--out",
                    os.path.join(self.out, "parking-garage.out.g2o")])
        keep = [line.replace(SHARED + os.sep, "../shared/") for line in text.splitlines()
                if not line.startswith("wrote")]
        self.section("Pose graph", "The back end's optimiser on the parking garage.",
                     "glintd posegraph ../shared/data/parking-garage.g2o --out OUT.g2o",
                     "```\n" + "\n".join(keep) + "\n```")

    def latency(self):
        d = self.simulate("warehouse", 3, 60)
        t = timing(run([self.glintd, "replay", os.path.join(d, "scan.pcap"), "--trajectory",
                        os.path.join(d, "realtime.tum"), "--no-publish", "--no-loop",
                        "--pace", "realtime"]))
        self.section(
            "Latency at the sensor's pace",
            "From a sweep's last packet to its published pose, with the capture read at the "
            "sensor's own pace (live over UDP: `bash scripts/latency_bench.sh`).",
            "glintd replay D/scan.pcap --trajectory D/realtime.tum --no-publish --no-loop "
            "--pace realtime",
            f"warehouse 3, 60 s: median {fmt(t['latency'][0], 1)} ms, "
            f"p99 {fmt(t['latency'][1], 1)} ms.")

    def peers(self):
        script = os.path.join(REPO, "scripts", "compare_peers.py")
        if not os.path.exists(script):
            return
        out = os.path.join(self.out, "peers")
        run([sys.executable, script, "--glintd", self.glintd, "--out", out])
        with open(os.path.join(out, "table.md")) as f:
            table = f.read().strip()
        self.section(
            "Compared with KISS-ICP",
            "Glint geometry only, Glint with intensity (both odometry only) and KISS-ICP with its "
            "defaults on the same simulated sweeps, evaluated by the same `glintd eval`. Each "
            "cell: drift / ATE RMSE / median wall time per sweep (mean CPU time per sweep, all "
            "threads).",
            "python3 scripts/compare_peers.py", table)

    def localisation(self):
        script = os.path.join(REPO, "scripts", "localisation_bench.py")
        runs = 4 if self.quick else 20
        text = run([sys.executable, script, "--glintd", self.glintd, "--runs", str(runs),
                    "--out", os.path.join(self.out, "localisation")])
        keep = [line for line in text.splitlines()
                if line.startswith(("run ", "mapping run", "that anchor", "keyframes:", "size:"))
                or "runs:" in line
                or line.startswith(("kidnaps:", "position RMSE", "of which", "with the map frame"))]
        self.section(
            "Localisation in a saved map",
            f"One warehouse mapped (150 s), {runs} runs of the same scene localised in its map "
            "(other routes, directions, starts, sensor units, a third of the goods moved, more "
            "movers, kidnaps) and scored without alignment through the mapping run's first pose "
            "(`glintd eval --no-align --anchor`); as a diagnostic, also in the map frame fitted to "
            "the whole mapping run (see docs/localisation.md, \"Accuracy in the map frame\").",
            f"python3 scripts/localisation_bench.py --runs {runs}",
            "```\n" + "\n".join(keep) + "\n```")

    def memory(self):
        script = os.path.join(REPO, "scripts", "memory_bench.py")
        if not os.path.exists(script):
            return
        lines = []
        for flags in ([], ["--slam"]):
            text = run([sys.executable, script, "--glintd", self.glintd, *flags])
            peak = [line for line in text.splitlines() if line.startswith("peak RSS")]
            lines.append(f"- {'SLAM' if flags else 'odometry'}: "
                         + (peak[-1] if peak else "no result"))
        self.section(
            "Memory",
            "Peak resident memory of a 600 s warehouse replay against a 60 s one (target: "
            "ratio ≤ 1.5).", "python3 scripts/memory_bench.py [--slam]", "\n".join(lines))


def git(*args):
    try:
        return subprocess.run(["git", "--no-optional-locks", "-C", REPO, *args],
                              stdout=subprocess.PIPE, stderr=subprocess.DEVNULL,
                              universal_newlines=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return ""


def host_state(glintd):
    """Commit, binary and load, taken before the runs."""
    commit = git("rev-parse", "--short", "HEAD") or "unknown"
    dirty = git("status", "--porcelain", "--", "core", "driver", "daemon", "sim", "ipc", "map",
                "capi", "tests", "Cargo.toml", "Cargo.lock")
    stamp = commit + (" with uncommitted changes to the Rust code" if dirty else "")
    built = os.path.getmtime(glintd)
    committed = git("log", "-1", "--format=%ct")
    stamp += f"; binary `{shown([glintd])}` built " + datetime.datetime.fromtimestamp(
        built).strftime("%Y-%m-%d %H:%M")
    if committed and built < int(committed):
        stamp += " (before that commit: rebuild, or leave out --glintd, for its figures)"
    cpu = ""
    try:
        with open("/proc/cpuinfo") as f:
            m = re.search(r"^model name\s*:\s*(.+)$", f.read(), re.M)
            cpu = m.group(1).strip() if m else ""
    except OSError:
        pass
    load = ", ".join(f"{x:.1f}" for x in os.getloadavg()) if hasattr(os, "getloadavg") else "?"
    return stamp, cpu, load


def header(quick, skipped, state):
    stamp, cpu, load = state
    mode = "python3 scripts/benchmarks.py" + (" --quick" if quick else "")
    lines = [
        "# Benchmarks",
        "",
        f"Commit **{stamp}**, {datetime.datetime.now().strftime('%Y-%m-%d %H:%M')}. "
        f"Written by `{mode}` from the output of the commands shown; do not edit by hand.",
        "",
        f"Host: {os.cpu_count()} logical cores{', ' + cpu if cpu else ''}, {platform.system()} "
        f"{platform.release()}; load average at the start {load}. Wall-clock times on a shared "
        "host spread by about ±20 % from one run to the next.",
    ]
    if quick:
        lines += ["", f"Quick mode: {QUICK_SECONDS} s runs (drift over 5–10 m segments only), "
                  "one bench run each; not comparable with the full runs' figures."]
    if skipped:
        lines += ["", "Not run this time: " + ", ".join(skipped) + "."]
    return "\n".join(lines) + "\n"


def find_glintd(path):
    if path:
        return os.path.abspath(path)
    built = os.path.join(REPO, "target", "release", "glintd")
    if shutil.which("cargo"):
        print("building glintd (cargo build --release -p glintd) ...", flush=True)
        run(["cargo", "build", "--release", "-p", "glintd"])
    if not os.access(built, os.X_OK):
        raise Failure("no target/release/glintd: install Rust or pass --glintd")
    return built


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true",
                    help=f"{QUICK_SECONDS} s runs, one bench run; no peers, memory or latency")
    ap.add_argument("--glintd", help="use this glintd binary instead of building it")
    ap.add_argument("--out", default=os.path.join(REPO, "target", "benchmarks"),
                    help="folder for the simulated runs (default target/benchmarks)")
    ap.add_argument("--doc", default=DOC, help="the page to write (default docs/benchmarks.md)")
    ap.add_argument("--repeat", type=int, default=None,
                    help="glintd bench runs per scenario (default 3, quick 1)")
    ap.add_argument("--no-peers", action="store_true", help="leave out compare_peers.py")
    ap.add_argument("--no-memory", action="store_true", help="leave out memory_bench.py")
    args = ap.parse_args()
    repeat = args.repeat or (1 if args.quick else 3)
    skipped = []
    try:
        glintd = find_glintd(args.glintd)
        os.makedirs(args.out, exist_ok=True)
        state = host_state(glintd)
        b = Bench(glintd, args.out, args.quick)
        print("odometry accuracy", flush=True)
        b.odometry()
        print("SLAM accuracy", flush=True)
        b.slam()
        print("odometry time on one core", flush=True)
        b.bench(repeat)
        print("the whole chain", flush=True)
        b.demo()
        print("pose graph", flush=True)
        b.posegraph()
        print("localisation", flush=True)
        b.localisation()
        if args.quick:
            skipped += ["latency at the sensor's pace", "KISS-ICP comparison", "memory"]
        else:
            print("latency", flush=True)
            b.latency()
            if args.no_peers:
                skipped.append("KISS-ICP comparison")
            else:
                print("KISS-ICP comparison", flush=True)
                b.peers()
            if args.no_memory:
                skipped.append("memory")
            else:
                print("memory", flush=True)
                b.memory()
        start_header = header(args.quick, skipped, state)
    except Failure as e:
        print(f"benchmarks: {e}", file=sys.stderr)
        return 1
    with open(args.doc, "w") as f:
        f.write(start_header + "\n" + "\n".join(b.sections))
    print(f"wrote {os.path.relpath(args.doc, REPO)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
