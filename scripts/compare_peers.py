#!/usr/bin/env python3
"""Glint beside KISS-ICP on the three simulated scenarios.

One command, from the repository root (any Python >= 3.8; nothing to install by hand):

    python3 scripts/compare_peers.py            # prints the table
    python3 scripts/compare_peers.py --readme   # also writes the table to docs/peers.md

For each scenario (warehouse, yard, corridor; seeds fixed below, 60 s each) it
  1. simulates the run: `glintd sim SCENARIO --seed N --seconds S` -> scan.pcap, groundtruth.tum;
  2. runs Glint on it twice, geometry only (`glintd replay --no-intensity`) and with intensity
     (`glintd replay`), and reads the median time per sweep from replay's printout and the
     replay's CPU time (getrusage of the child) divided by its sweeps;
  3. decodes the same capture with our own `glintd decode` (binary PLY: every return with its
     sweep index and firing time) and runs KISS-ICP through its Python API (`KissICP` with
     per-point timestamps, so it deskews; two threads), one pose per sweep stamped, as Glint's,
     with the sweep's reference time: its last return's time. KISS-ICP deskews to that same
     instant (the end of the sweep), and its poses, like Glint's, are the sensor's in the first
     sweep's sensor frame;
  4. evaluates all three trajectories with the same `glintd eval EST.tum GT.tum`: drift (KITTI
     style, % over 5-50 m segments) and ATE RMSE after SE(3) alignment.

KISS-ICP (PyPI `kiss-icp`, pinned below) is installed into its own virtual environment,
target/peers-venv, on the first run; the script re-runs itself there for step 3
(`--kiss-worker`). Outputs go to target/peers/<scenario>-s<seed>/ (trajectories, logs,
results.json); the table also goes to target/peers/table.md.

Times: the median wall-clock time per sweep, and the mean CPU time per sweep (all threads),
which a loaded machine inflates far less. Glint runs odometry only (`--no-loop`, as KISS-ICP is
odometry) in its pipeline: the front end and the odometry on two threads (its CPU time also
holds reading and decoding the capture, ~1 % of it); KISS-ICP is limited to two threads (its
`max_num_threads`) and timed around `register_frame` alone.
With --one-thread it times instead, on one core (`taskset -c 0`), `glintd bench` (the
odometry on one thread: calibration, features, deskew, alignment, map update; decoding
untimed) against KISS-ICP with `max_num_threads = 1` timed around `register_frame` (decoding
untimed), on the same captures, alternating the two --rounds times (default 3) in one run, and
prints each one's median per-sweep time (the median of its rounds' medians) and the ratio.

Not part of the test suite: it needs PyPI and takes several minutes (2 cores: ~10-20 min).
"""
import argparse
import datetime
import json
import os
import re
import resource
import shutil
import subprocess
import sys
import time

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
VENV = os.path.join(REPO, "target", "peers-venv")
KISS_ICP = "kiss-icp==1.3.0"
KISS_THREADS = 2

# The scenarios and seeds, fixed: the same as the odometry table in README.md.
SCENARIOS = [("warehouse", 3), ("yard", 7), ("corridor", 5)]
SECONDS = 60.0

README_HEADING = "## Compared with KISS-ICP"
COMMAND = "python3 scripts/compare_peers.py --readme"


class Failure(Exception):
    """A step failed; the message says which and where its log is."""


def children_cpu_s():
    """CPU seconds (user + system) of all waited-for children so far."""
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def run(cmd, log_path=None, env=None):
    """Runs cmd, returns its stdout; on failure raises Failure naming the command and log."""
    proc = subprocess.run(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                          universal_newlines=True, env=env)
    if log_path:
        with open(log_path, "w") as f:
            f.write("$ " + " ".join(cmd) + "\n" + proc.stdout)
    if proc.returncode != 0:
        tail = "\n".join(proc.stdout.strip().splitlines()[-15:])
        where = f" (log: {log_path})" if log_path else ""
        raise Failure(f"command failed with status {proc.returncode}{where}:\n  "
                      + " ".join(cmd) + "\n" + tail)
    return proc.stdout


def parse_float(pattern, text, what):
    m = re.search(pattern, text)
    if not m:
        raise Failure(f"cannot find {what} in:\n{text}")
    return float(m.group(1))


# ---------------------------------------------------------------------------------------------
# The KISS-ICP side: runs inside the venv, reads a `glintd decode` PLY.

def read_decoded_ply(path):
    """Returns (structured array of returns) from `glintd decode ... --out X.ply`."""
    import numpy as np

    types = {"uint": "<u4", "double": "<f8", "uchar": "u1", "float": "<f4"}
    fields = []
    count = None
    with open(path, "rb") as f:
        if f.readline().strip() != b"ply":
            raise Failure(f"{path}: not a PLY file")
        while True:
            line = f.readline()
            if not line:
                raise Failure(f"{path}: PLY header has no end_header")
            words = line.decode("ascii").split()
            if words[:1] == ["format"] and words[1] != "binary_little_endian":
                raise Failure(f"{path}: expected binary_little_endian, got {words[1]}")
            if words[:2] == ["element", "vertex"]:
                count = int(words[2])
            elif words[:1] == ["property"]:
                fields.append((words[2], types[words[1]]))
            elif words[:1] == ["end_header"]:
                offset = f.tell()
                break
    needed = {"sweep", "time_ns", "x", "y", "z"}
    if count is None or not needed <= {name for name, _ in fields}:
        raise Failure(f"{path}: PLY lacks a vertex count or one of {sorted(needed)}")
    return np.memmap(path, dtype=np.dtype(fields), mode="r", offset=offset, shape=(count,))


def kiss_worker(ply, out_tum, out_json, threads=KISS_THREADS):
    """Runs KISS-ICP over every sweep of the PLY on `threads` threads; writes TUM poses and
    per-sweep times."""
    import numpy as np
    from kiss_icp.config import KISSConfig
    from kiss_icp.kiss_icp import KissICP

    points = read_decoded_ply(ply)
    sweep = np.asarray(points["sweep"])
    starts = np.concatenate(([0], np.flatnonzero(np.diff(sweep)) + 1, [len(sweep)]))

    # KISS-ICP's own defaults (as its CLI sets them): max range 100 m, voxel = max range / 100,
    # deskew on; only the thread count is set.
    config = KISSConfig()
    config.data.deskew = True
    config.registration.max_num_threads = threads
    config.mapping.voxel_size = config.data.max_range / 100.0
    odometry = KissICP(config=config)

    times_ms, cpu_ms = [], []
    with open(out_tum, "w") as tum:
        for a, b in zip(starts[:-1], starts[1:]):
            block = points[a:b]
            time_ns = np.asarray(block["time_ns"], dtype=np.float64)
            xyz = np.stack([block["x"], block["y"], block["z"]], axis=1).astype(np.float64)
            # Seconds since the sweep's first return; KISS-ICP normalises them per sweep and
            # deskews to the latest one.
            stamps = (time_ns - time_ns[0]) * 1e-9
            t0, c0 = time.perf_counter(), time.process_time()
            odometry.register_frame(xyz, stamps)
            times_ms.append((time.perf_counter() - t0) * 1e3)
            cpu_ms.append((time.process_time() - c0) * 1e3)
            pose = odometry.last_pose
            # Glint's reference time: the sweep's last return (in the decoder's order).
            ref_ns = int(round(time_ns[-1]))
            q = quaternion(pose[:3, :3])
            tum.write("%d.%09d %.6f %.6f %.6f %.9f %.9f %.9f %.9f\n" % (
                ref_ns // 10**9, ref_ns % 10**9, pose[0, 3], pose[1, 3], pose[2, 3], *q))
    with open(out_json, "w") as f:
        json.dump({"sweeps": len(times_ms), "times_ms": times_ms, "cpu_ms": cpu_ms,
                   "kiss_icp": kiss_version(), "threads": threads,
                   "voxel_size": config.mapping.voxel_size,
                   "max_range": config.data.max_range}, f)


def kiss_version():
    try:
        from importlib.metadata import version
        return version("kiss-icp")
    except Exception:  # noqa: BLE001 - only for the record
        return "unknown"


def quaternion(r):
    """(qx, qy, qz, qw) of a rotation matrix (Shepperd's method)."""
    import numpy as np

    t = np.trace(r)
    if t > 0:
        s = 2.0 * np.sqrt(1.0 + t)
        q = [(r[2, 1] - r[1, 2]) / s, (r[0, 2] - r[2, 0]) / s, (r[1, 0] - r[0, 1]) / s, s / 4]
    else:
        i = int(np.argmax(np.diag(r)))
        j, k = (i + 1) % 3, (i + 2) % 3
        s = 2.0 * np.sqrt(1.0 + r[i, i] - r[j, j] - r[k, k])
        q = [0.0, 0.0, 0.0, (r[k, j] - r[j, k]) / s]
        q[i] = s / 4
        q[j] = (r[j, i] + r[i, j]) / s
        q[k] = (r[k, i] + r[i, k]) / s
    q = np.array(q)
    return q / np.linalg.norm(q)


# ---------------------------------------------------------------------------------------------
# The driver side: plain Python, runs glintd and the worker.

def venv_python():
    """The venv's interpreter, creating the venv and installing KISS-ICP on first use."""
    python = os.path.join(VENV, "bin", "python")
    stamp = os.path.join(VENV, ".installed")
    if os.path.exists(stamp) and open(stamp).read().strip() == KISS_ICP:
        return python
    print(f"installing {KISS_ICP} into {os.path.relpath(VENV, REPO)} (first run only) ...",
          flush=True)
    if not os.path.exists(python):
        run([sys.executable, "-m", "venv", VENV])
    run([python, "-m", "pip", "install", "--quiet", "--upgrade", "pip"])
    run([python, "-m", "pip", "install", "--quiet", KISS_ICP])
    with open(stamp, "w") as f:
        f.write(KISS_ICP + "\n")
    return python


def build_glintd():
    print("building glintd (cargo build --release -p glintd) ...", flush=True)
    run(["cargo", "build", "--release", "-p", "glintd"])
    return os.path.join(REPO, "target", "release", "glintd")


def evaluate(glintd, est, gt, log):
    text = run([glintd, "eval", est, gt], log)
    if "relative error: no segment fits" in text:
        raise Failure(f"{est}: the run is too short for 5 m segments")
    return {
        "drift_pct": parse_float(r"drift ([0-9.]+|NaN|inf) %", text, "the drift"),
        "drift_deg_per_m": parse_float(r"% / ([0-9.]+|NaN|inf) °/m", text, "the rotational drift"),
        "ate_rmse_m": parse_float(r"ATE: RMSE ([0-9.]+|NaN|inf) m", text, "the ATE"),
    }


def median(values):
    v = sorted(values)
    n = len(v)
    return v[n // 2] if n % 2 else 0.5 * (v[n // 2 - 1] + v[n // 2])


def percentile(values, q):
    v = sorted(values)
    return v[int(round((len(v) - 1) * q))]


def simulate(glintd, scenario, seed, seconds, out_root, reuse):
    """The scenario's folder, simulated unless --reuse finds the same run there."""
    d = os.path.join(out_root, f"{scenario}-s{seed}")
    os.makedirs(d, exist_ok=True)
    pcap = os.path.join(d, "scan.pcap")
    stamp = os.path.join(d, "sim.args")
    sim_args = f"{scenario} --seed {seed} --seconds {seconds:g}"
    if not (reuse and os.path.exists(pcap) and os.path.exists(stamp)
            and open(stamp).read().strip() == sim_args):
        print(f"[{scenario}] simulating {seconds:g} s (seed {seed}) ...", flush=True)
        run([glintd, "sim", scenario, "--seed", str(seed), "--seconds", f"{seconds:g}",
             "--out", d], os.path.join(d, "sim.log"))
        with open(stamp, "w") as f:
            f.write(sim_args + "\n")
        for stale in ("kiss_icp.tum", "kiss_icp.json"):
            if os.path.exists(os.path.join(d, stale)):
                os.remove(os.path.join(d, stale))
    return d


def run_scenario(glintd, python, scenario, seed, seconds, out_root, reuse, keep_ply):
    d = simulate(glintd, scenario, seed, seconds, out_root, reuse)
    pcap = os.path.join(d, "scan.pcap")
    gt = os.path.join(d, "groundtruth.tum")
    result = {"scenario": scenario, "seed": seed, "seconds": seconds}
    for name, flags in (("glint_geometry", ["--no-intensity"]), ("glint_intensity", [])):
        print(f"[{scenario}] glintd replay{' ' + ' '.join(flags) if flags else ''} ...",
              flush=True)
        est = os.path.join(d, name + ".tum")
        cpu0 = children_cpu_s()
        text = run([glintd, "replay", pcap, "--trajectory", est, "--no-publish", "--no-loop"] + flags,
                   os.path.join(d, name + ".log"))
        cpu_s = children_cpu_s() - cpu0
        m = re.search(r"per sweep: median ([0-9.]+) ms, p99 ([0-9.]+) ms", text)
        if not m:
            raise Failure(f"no 'per sweep' timing in glintd replay's output:\n{text}")
        sweeps = parse_float(r"sweeps: ([0-9]+)", text, "the sweep count")
        result[name] = dict(evaluate(glintd, est, gt, os.path.join(d, name + ".eval")),
                            median_ms=float(m.group(1)), p99_ms=float(m.group(2)),
                            cpu_ms=cpu_s * 1e3 / max(sweeps, 1), sweeps=int(sweeps))

    kiss_tum = os.path.join(d, "kiss_icp.tum")
    kiss_json = os.path.join(d, "kiss_icp.json")
    if not (reuse and os.path.exists(kiss_tum) and os.path.exists(kiss_json)):
        ply = os.path.join(d, "sweeps.ply")
        print(f"[{scenario}] glintd decode -> PLY, KISS-ICP ({KISS_THREADS} threads) ...",
              flush=True)
        run([glintd, "decode", pcap, "--out", ply], os.path.join(d, "decode.log"))
        try:
            run([python, os.path.abspath(__file__), "--kiss-worker", ply, kiss_tum, kiss_json],
                os.path.join(d, "kiss_icp.log"))
        finally:
            if not keep_ply and os.path.exists(ply):
                os.remove(ply)
    with open(kiss_json) as f:
        kiss = json.load(f)
    result["kiss_icp"] = dict(evaluate(glintd, kiss_tum, gt, os.path.join(d, "kiss_icp.eval")),
                              median_ms=median(kiss["times_ms"]),
                              p99_ms=percentile(kiss["times_ms"], 0.99),
                              cpu_ms=sum(kiss["cpu_ms"]) / max(len(kiss["cpu_ms"]), 1),
                              sweeps=kiss["sweeps"], version=kiss["kiss_icp"],
                              threads=kiss["threads"], voxel_size=kiss["voxel_size"],
                              max_range=kiss["max_range"])
    with open(os.path.join(d, "results.json"), "w") as f:
        json.dump(result, f, indent=2)
    return result


def one_thread(glintd, python, scenario, seed, seconds, out_root, reuse, rounds):
    """Glint's `glintd bench` and KISS-ICP on one thread each, pinned to core 0, alternating
    `rounds` times on the same capture: each round's median per-sweep time, in ms."""
    if shutil.which("taskset") is None:
        raise Failure("taskset not found (util-linux): it pins both to one core")
    d = simulate(glintd, scenario, seed, seconds, out_root, reuse)
    pcap = os.path.join(d, "scan.pcap")
    ply = os.path.join(d, "sweeps.ply")
    run([glintd, "decode", pcap, "--out", ply], os.path.join(d, "decode.log"))
    glint, kiss = [], []
    try:
        for k in range(rounds):
            print(f"[{scenario}] round {k + 1} of {rounds}: glintd bench, KISS-ICP (1 thread), "
                  f"on core 0 ...", flush=True)
            text = run(["taskset", "-c", "0", glintd, "bench", pcap],
                       os.path.join(d, f"bench-{k}.log"))
            glint.append(parse_float(r"per sweep: median ([0-9.]+) ms", text,
                                     "glintd bench's median"))
            out = os.path.join(d, f"kiss_icp_1t-{k}")
            run(["taskset", "-c", "0", python, os.path.abspath(__file__), "--kiss-worker", ply,
                 out + ".tum", out + ".json", "--kiss-threads", "1"], out + ".log")
            with open(out + ".json") as f:
                kiss.append(median(json.load(f)["times_ms"]))
    finally:
        if os.path.exists(ply):
            os.remove(ply)
    return {"scenario": scenario, "seed": seed, "glint_ms": glint, "kiss_ms": kiss}


def one_thread_table(results, rounds):
    lines = [
        f"| scenario (seed) | glintd bench, median ms per sweep | KISS-ICP 1 thread, median ms "
        f"per sweep | KISS-ICP / Glint |",
        "| --- | --- | --- | --- |",
    ]
    for r in results:
        g, k = median(r["glint_ms"]), median(r["kiss_ms"])
        lines.append(f"| {r['scenario']} ({r['seed']}) | {g:.2f} | {k:.2f} | {k / g:.1f}x |")
    return "\n".join(lines) + (f"\n\nEach the median of {rounds} rounds' medians, the two "
                               f"alternating on core 0.")


def table(results):
    def cell(r):
        return (f"{r['drift_pct']:.2f} % / {r['ate_rmse_m']:.3f} m / "
                f"{r['median_ms']:.1f} ms ({r['cpu_ms']:.1f} ms CPU)")

    lines = [
        "| scenario (seed, s) | Glint geometry only | Glint with intensity | KISS-ICP |",
        "| --- | --- | --- | --- |",
    ]
    for r in results:
        lines.append(f"| {r['scenario']} ({r['seed']}, {r['seconds']:g} s) | "
                     f"{cell(r['glint_geometry'])} | {cell(r['glint_intensity'])} | "
                     f"{cell(r['kiss_icp'])} |")
    return "\n".join(lines)


def git_commit():
    try:
        commit = subprocess.run(["git", "-C", REPO, "rev-parse", "--short", "HEAD"],
                                stdout=subprocess.PIPE, universal_newlines=True,
                                check=True).stdout.strip()
        dirty = subprocess.run(["git", "-C", REPO, "status", "--porcelain", "--",
                                "core", "driver", "daemon", "sim", "ipc", "Cargo.lock"],
                               stdout=subprocess.PIPE, universal_newlines=True).stdout.strip()
        return commit + (" with uncommitted changes to the Rust code" if dirty else "")
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def readme_section(results, commit):
    kiss = results[0]["kiss_icp"]
    today = datetime.date.today().isoformat()
    peer = (f"(PyPI `kiss-icp` {kiss['version']} with its defaults: {kiss['voxel_size']:g} m "
            f"voxels, {kiss['max_range']:g} m range, per-point deskew;")
    return f"""{README_HEADING}

Glint (geometry only, `glintd replay --no-intensity`, and with intensity) beside KISS-ICP
{peer}
{kiss['threads']} threads) on the same simulated sweeps, produced by one command:

```sh
{COMMAND}
```

It simulates each scenario, replays it through Glint twice, decodes the same capture with
`glintd decode` for KISS-ICP (run through its Python API in a venv it installs under
`target/peers-venv`), stamps every KISS-ICP pose with the sweep's reference time (its last
return, as Glint does) and evaluates all three with the same `glintd eval`. Each cell:
drift (KITTI style, over 5–50 m segments) / ATE RMSE after SE(3) alignment / median wall time
per sweep (mean CPU time per sweep, all threads; Glint's median is the front end plus the
odometry, which run on two threads, KISS-ICP's its `register_frame` on two threads). Glint runs
odometry only (`--no-loop`). Measured on {today} at commit {commit} on a 2-core machine:

{table(results)}

Outputs and logs are in `target/peers/`.
"""


def update_readme(section):
    """Writes the table to docs/peers.md, which the README links to (figures stay out of the
    README itself)."""
    path = os.path.join(REPO, "docs", "peers.md")
    with open(path, "w") as f:
        f.write("# " + section.lstrip("#").lstrip())
    print(f"{path} written")


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--glintd", help="use this glintd binary instead of building it")
    ap.add_argument("--out", default=os.path.join(REPO, "target", "peers"),
                    help="output folder (default: target/peers)")
    ap.add_argument("--seconds", type=float, default=SECONDS,
                    help=f"simulated seconds per scenario (default {SECONDS:g}; >= 60 for "
                         "the README)")
    ap.add_argument("--scenarios", default=",".join(s for s, _ in SCENARIOS),
                    help="comma-separated subset of the scenarios")
    ap.add_argument("--readme", action="store_true",
                    help="also write the table to docs/peers.md")
    ap.add_argument("--reuse", action="store_true",
                    help="reuse simulated runs and KISS-ICP results already in --out (same "
                         "scenario, seed and length); Glint is always rerun")
    ap.add_argument("--keep-ply", action="store_true",
                    help="keep the decoded sweeps (sweeps.ply, ~0.5 GB per minute)")
    ap.add_argument("--one-thread", action="store_true",
                    help="time glintd bench against KISS-ICP on one thread each, pinned to "
                         "one core, alternating (no accuracy figures)")
    ap.add_argument("--rounds", type=int, default=3,
                    help="with --one-thread: alternations of the two (default 3)")
    ap.add_argument("--kiss-worker", nargs=3, metavar=("PLY", "OUT_TUM", "OUT_JSON"),
                    help=argparse.SUPPRESS)
    ap.add_argument("--kiss-threads", type=int, default=KISS_THREADS, help=argparse.SUPPRESS)
    args = ap.parse_args()

    try:
        if args.kiss_worker:
            kiss_worker(*args.kiss_worker, threads=args.kiss_threads)
            return 0
        seeds = dict(SCENARIOS)
        wanted = [s for s in args.scenarios.split(",") if s]
        unknown = [s for s in wanted if s not in seeds]
        if unknown:
            raise Failure(f"unknown scenario(s) {unknown}; known: {list(seeds)}")
        if args.readme and args.one_thread:
            raise Failure("--readme writes the accuracy table; --one-thread only times")
        if args.readme and (args.seconds < 60 or len(wanted) < len(SCENARIOS)):
            raise Failure("--readme needs all three scenarios and --seconds >= 60")
        if shutil.which("cargo") is None and not args.glintd:
            raise Failure("cargo not found: install Rust or pass --glintd")
        glintd = os.path.abspath(args.glintd) if args.glintd else build_glintd()
        if not os.access(glintd, os.X_OK):
            raise Failure(f"{glintd} is not an executable")
        python = venv_python()
        os.makedirs(args.out, exist_ok=True)
        if args.one_thread:
            if args.rounds < 1:
                raise Failure("--rounds must be at least 1")
            timed = [one_thread(glintd, python, s, seeds[s], args.seconds, args.out,
                                args.reuse, args.rounds) for s in wanted]
            text = one_thread_table(timed, args.rounds)
            with open(os.path.join(args.out, "one-thread.md"), "w") as f:
                f.write(text + "\n")
            print()
            print(text)
            return 0
        results = [run_scenario(glintd, python, s, seeds[s], args.seconds, args.out,
                                args.reuse, args.keep_ply) for s in wanted]
    except Failure as e:
        print(f"compare_peers: {e}", file=sys.stderr)
        return 1

    text = table(results)
    with open(os.path.join(args.out, "table.md"), "w") as f:
        f.write(text + "\n")
    print()
    print("drift (5-50 m segments) / ATE RMSE / median wall time per sweep (mean CPU time)")
    print(text)
    for r in results:
        for name in ("glint_geometry", "glint_intensity", "kiss_icp"):
            x = r[name]
            print(f"  {r['scenario']:9s} {name:15s} {x['drift_deg_per_m']:.4f} deg/m, "
                  f"p99 {x['p99_ms']:.1f} ms, {x['sweeps']} sweeps")
    if args.readme:
        update_readme(readme_section(results, git_commit()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
