#!/usr/bin/env python3
"""Peak memory of `glintd replay` on a long run against a short one.

    python3 scripts/memory_bench.py                   # 10-minute vs 1-minute warehouse run
    python3 scripts/memory_bench.py --glintd target/release/glintd --long 300
    python3 scripts/memory_bench.py --slam            # the same with the back end

Simulates a warehouse run of --short and of --long seconds (same seed), replays each through
`glintd replay CAPTURE --trajectory OUT.tum --no-publish --no-loop` (the odometry; with
--slam, the full SLAM, whose graph grows with the path: a node per keyframe, while a keyframe
that revisits a place releases its points) (add --map to also build the whole run's map) and
reads each replay's peak resident set size from the kernel: wait4()'s ru_maxrss for that child
alone (and /proc/PID/status VmHWM, sampled while it runs, as a cross-check). Prints both peaks
and their ratio, and exits 1 if long / short > 1.5 (memory must stay flat on an endless run).

The 10-minute replay takes several minutes (6,000 sweeps at Glint's current speed, longer on a
loaded machine); the simulated captures go to target/memory-bench/ (~90 MB per simulated
minute) and are reused by later runs with the same arguments. Plain Python 3, no packages.
Not part of the test suite.
"""
import argparse
import os
import re
import subprocess
import sys
import threading
import time

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
FLOOR = 1.5


class Failure(Exception):
    """A step failed; the message says which."""


def check(cmd, log_path):
    with open(log_path, "w") as log:
        status = subprocess.call(cmd, stdout=log, stderr=subprocess.STDOUT)
    if status != 0:
        raise Failure(f"status {status}: {' '.join(cmd)} (log: {log_path})")


def simulate(glintd, seed, seconds, out_root):
    d = os.path.join(out_root, f"warehouse-s{seed}-{seconds:g}s")
    os.makedirs(d, exist_ok=True)
    pcap = os.path.join(d, "scan.pcap")
    stamp = os.path.join(d, "sim.args")
    sim_args = f"warehouse --seed {seed} --seconds {seconds:g}"
    if os.path.exists(pcap) and os.path.exists(stamp) and open(stamp).read().strip() == sim_args:
        print(f"reusing {os.path.relpath(pcap, REPO)}", flush=True)
        return d
    print(f"simulating {seconds:g} s of a warehouse (seed {seed}) ...", flush=True)
    check([glintd, "sim", "warehouse", "--seed", str(seed), "--seconds", f"{seconds:g}",
           "--out", d], os.path.join(d, "sim.log"))
    with open(stamp, "w") as f:
        f.write(sim_args + "\n")
    return d


def vm_hwm_kib(pid):
    try:
        with open(f"/proc/{pid}/status") as f:
            m = re.search(r"^VmHWM:\s+(\d+) kB", f.read(), re.M)
        return int(m.group(1)) if m else 0
    except OSError:
        return 0


def replay_peak(glintd, run_dir, with_map, slam):
    """Replays the run; returns (peak RSS in MiB from wait4, VmHWM sampled, seconds, log)."""
    cmd = [glintd, "replay", os.path.join(run_dir, "scan.pcap"),
           "--trajectory", os.path.join(run_dir, "est.tum"), "--no-publish"]
    if not slam:
        cmd += ["--no-loop"]
    if with_map:
        cmd += ["--map", os.path.join(run_dir, "map.pcd")]
    log_path = os.path.join(run_dir, "replay.log")
    print(f"  $ {' '.join(os.path.relpath(c, REPO) if c.startswith(REPO) else c for c in cmd)}",
          flush=True)
    start = time.monotonic()
    with open(log_path, "w") as log:
        proc = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT)
        sampled = [0]

        def sample():
            while proc.returncode is None:
                sampled[0] = max(sampled[0], vm_hwm_kib(proc.pid))
                time.sleep(0.5)

        sampler = threading.Thread(target=sample, daemon=True)
        sampler.start()
        _, status, usage = os.wait4(proc.pid, 0)
        proc.returncode = os.waitstatus_to_exitcode(status) if hasattr(
            os, "waitstatus_to_exitcode") else status >> 8
    elapsed = time.monotonic() - start
    if proc.returncode != 0:
        raise Failure(f"glintd replay failed with status {proc.returncode} (log: {log_path})")
    # ru_maxrss is in KiB on Linux.
    return usage.ru_maxrss / 1024.0, sampled[0] / 1024.0, elapsed, log_path


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--glintd", help="use this glintd binary instead of building it")
    ap.add_argument("--short", type=float, default=60.0, help="short run, s (default 60)")
    ap.add_argument("--long", type=float, default=600.0, help="long run, s (default 600)")
    ap.add_argument("--seed", type=int, default=1, help="warehouse seed (default 1)")
    ap.add_argument("--map", action="store_true",
                    help="also build and write the whole run's map (--map OUT.pcd)")
    ap.add_argument("--slam", action="store_true",
                    help="replay with the back end (default: odometry only, --no-loop)")
    ap.add_argument("--out", default=os.path.join(REPO, "target", "memory-bench"),
                    help="folder for the simulated runs (default target/memory-bench)")
    args = ap.parse_args()
    if sys.platform != "linux":
        print("memory_bench: Linux only (wait4 ru_maxrss in KiB, /proc)", file=sys.stderr)
        return 1
    try:
        if args.glintd:
            glintd = os.path.abspath(args.glintd)
        else:
            print("building glintd (cargo build --release -p glintd) ...", flush=True)
            check(["cargo", "build", "--release", "-p", "glintd"],
                  os.path.join(REPO, "target", "memory-bench-build.log"))
            glintd = os.path.join(REPO, "target", "release", "glintd")
        if not os.access(glintd, os.X_OK):
            raise Failure(f"{glintd} is not an executable")
        peaks = {}
        for seconds in (args.short, args.long):
            run_dir = simulate(glintd, args.seed, seconds, args.out)
            rss, hwm, elapsed, log = replay_peak(glintd, run_dir, args.map, args.slam)
            with open(log) as f:
                text = f.read()
            sweeps = re.search(r"sweeps: (\d+)", text)
            timing = re.search(r"per sweep: median ([0-9.]+) ms", text)
            backend = re.search(r"back end: (\d+) keyframes.*; (\d+) keyframes released", text)
            print(f"  {seconds:g} s run: {sweeps.group(1) if sweeps else '?'} sweeps, "
                  f"peak RSS {rss:.1f} MiB (VmHWM sampled {hwm:.1f} MiB), "
                  f"replay {elapsed:.0f} s wall"
                  + (f", median {timing.group(1)} ms per sweep" if timing else "")
                  + (f", {backend.group(1)} keyframes ({backend.group(2)} released)"
                     if backend else ""), flush=True)
            peaks[seconds] = rss
    except Failure as e:
        print(f"memory_bench: {e}", file=sys.stderr)
        return 1
    ratio = peaks[args.long] / peaks[args.short]
    verdict = "ok" if ratio <= FLOOR else "ABOVE THE FLOOR"
    print(f"peak RSS: {args.long:g} s run {peaks[args.long]:.1f} MiB, {args.short:g} s run "
          f"{peaks[args.short]:.1f} MiB; ratio {ratio:.2f} (floor <= {FLOOR}): {verdict}")
    return 0 if ratio <= FLOOR else 1


if __name__ == "__main__":
    sys.exit(main())
