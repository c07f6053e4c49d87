#!/usr/bin/env python3
"""Localisation in a saved site map, measured on simulated runs of one warehouse.

    python3 scripts/localisation_bench.py                 # 20 runs, prints the table
    python3 scripts/localisation_bench.py --runs 5 --glintd target/release/glintd

Maps the warehouse once (`glintd sim warehouse --seed S --path-seed P --seconds 150`, then
`glintd replay --save-map`), then simulates --runs further runs of the same scene that differ
in route (another path seed inside the mapped area), direction, start point, sensor unit, goods
moved, people and forklifts, and a kidnap, and localises each with `glintd replay --localise`.
Every run is scored with `glintd eval --no-align --anchor` against the simulator's ground truth
(the map frame anchored through the mapping run's first pose), the position error also split
into horizontal and vertical. A pose more than 0.5 m or 5° off that was published as tracked is
a wrong pose. As a diagnostic, each run is also scored in the map frame fitted to the whole
mapping run (SE(3)): the anchor carries its one pose's own error (under vibration, a sweep's
tilt at that instant), which the distance from the start multiplies.

Plain Python 3, no packages. Files go to target/localisation-bench/. Not part of the test suite
(the tests check a handful of these runs: tests/tests/localisation_sim.rs).
"""

import argparse
import os
import random
import re
import subprocess
import sys

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SEED = 21
MAP_PATH_SEED = 2
# Routes that lie inside the mapped one (the same two double rows, or one of them).
ROUTES = [2, 4]


def sh(args, **kw):
    return subprocess.run(args, check=True, capture_output=True, text=True, **kw).stdout


def figures(text):
    """The figures `glintd eval --no-align` prints, by name."""
    out = {}
    for key, pattern in [
        ("position_rmse", r"position RMSE: ([\d.]+) m"),
        ("heading_rmse", r"heading RMSE: ([\d.]+) °"),
        ("max_position", r"max position error: ([\d.]+) m"),
        ("wrong", r"wrong poses: (\d+) of"),
        ("horizontal", r"^horizontal RMSE: ([\d.]+) m"),
        ("vertical", r"vertical RMSE: ([\d.]+) m$"),
        ("anchor_tilt", r"anchor is ([\d.]+)° of tilt"),
        ("anchor_heading", r"and (-?[\d.]+)° of heading off it"),
        ("fitted_position", r"fitted to the whole mapping run .*position RMSE ([\d.]+) m"),
        ("fitted_heading", r"fitted to the whole mapping run .*heading RMSE ([\d.]+) °"),
    ]:
        m = re.search(pattern, text, re.MULTILINE)
        out[key] = float(m.group(1)) if m else float("nan")
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--glintd", help="use this glintd binary instead of building it")
    ap.add_argument("--runs", type=int, default=20)
    ap.add_argument("--seconds", type=float, default=25.0, help="length of each localisation run")
    ap.add_argument("--out", default=os.path.join(REPO, "target", "localisation-bench"))
    ap.add_argument("--config", help="a daemon configuration for the mapping and localisation "
                    "replays (`glintd replay --config`)")
    args = ap.parse_args()
    config = ["--config", args.config] if args.config else []
    glintd = args.glintd
    if not glintd:
        sh(["cargo", "build", "--release", "-p", "glintd"], cwd=REPO)
        glintd = os.path.join(REPO, "target", "release", "glintd")
    os.makedirs(args.out, exist_ok=True)
    d = lambda *p: os.path.join(args.out, *p)

    mapping = d("mapping")
    if not os.path.exists(os.path.join(mapping, "scan.pcap")):
        sh([glintd, "sim", "warehouse", "--seed", str(SEED), "--path-seed", str(MAP_PATH_SEED),
            "--seconds", "150", "--out", mapping])
    sh([glintd, "replay", os.path.join(mapping, "scan.pcap"), "--no-publish",
        "--save-map", d("site.glintmap"), "--trajectory", d("mapping.tum")] + config)
    info = sh([glintd, "map", "info", d("site.glintmap")])
    print(info.strip())
    mapping_gt = os.path.join(mapping, "groundtruth_dense.tum")
    own = figures(sh([glintd, "eval", "--no-align", "--anchor", d("mapping.tum"), mapping_gt,
                      d("mapping.tum"), mapping_gt]))
    print(f"mapping run against its ground truth, anchored at its first pose: "
          f"{own['position_rmse']:.3f} m ({own['horizontal']:.3f} horizontal, "
          f"{own['vertical']:.3f} vertical), {own['heading_rmse']:.3f}° RMSE")
    print(f"that anchor is {own['anchor_tilt']:.3f}° of tilt and {own['anchor_heading']:.3f}° of "
          f"heading off the map frame fitted to the whole mapping run (SE(3)); with the fitted "
          f"frame the mapping run is at {own['fitted_position']:.3f} m, "
          f"{own['fitted_heading']:.3f}°")

    rng = random.Random(1)
    rows = []
    for i in range(args.runs):
        flags = ["--path-seed", str(ROUTES[i % len(ROUTES)]),
                 "--start-fraction", f"{rng.random() * 0.95:.3f}"]
        if i % 2:
            flags.append("--reverse")
        kind = i % 5
        if kind == 1:
            flags += ["--unit-seed", str(100 + i)]
        elif kind == 2:
            flags += ["--change", "0.33", "--change-seed", str(i)]
        elif kind == 3:
            flags += ["--movers", "6"]
        elif kind == 4:
            flags += ["--kidnap", f"{8 + rng.random() * 8:.1f}"]
        run = d(f"run{i:02}")
        try:
            sh([glintd, "sim", "warehouse", "--seed", str(SEED), "--seconds",
                str(args.seconds), "--out", run] + flags)
        except subprocess.CalledProcessError as e:
            print(f"run {i}: {' '.join(flags)}: not simulated ({e.stderr.strip()})")
            continue
        text = sh([glintd, "replay", os.path.join(run, "scan.pcap"), "--no-publish",
                   "--localise", d("site.glintmap"), "--trajectory", run + ".tum"] + config)
        relocs = [float(x) for x in re.findall(r"relocalised at t = [\d.]+ s after ([\d.]+) s", text)]
        verified = re.search(r"localisation: (\d+) of (\d+) sweeps", text)
        gt = os.path.join(run, "groundtruth_dense.tum")
        try:
            truth = figures(sh([glintd, "eval", "--no-align", "--anchor", d("mapping.tum"),
                                mapping_gt, run + ".tum", gt]))
        except subprocess.CalledProcessError:
            truth = figures("")
        rows.append((i, " ".join(flags), relocs, verified.groups() if verified else ("0", "?"),
                     truth))
        print(f"run {i:2}: {' '.join(flags):70} relocalised after {relocs} s; "
              f"{verified.group(1) if verified else 0} of {verified.group(2) if verified else '?'} "
              f"verified; {truth['position_rmse']:.3f} m ({truth['horizontal']:.3f} h, "
              f"{truth['vertical']:.3f} v), {truth['heading_rmse']:.3f}°, "
              f"wrong {truth['wrong']:.0f}; fitted frame {truth['fitted_position']:.3f} m, "
              f"{truth['fitted_heading']:.3f}°", flush=True)

    found = sum(1 for r in rows if r[2] and r[2][0] <= 2.0)
    wrong = sum(r[4]["wrong"] for r in rows)
    print(f"\n{len(rows)} runs: relocalised within 2 s of sensor data in {found}; "
          f"wrong poses published as tracked: {wrong:.0f}")
    kid = [r for r in rows if "--kidnap" in r[1]]
    back = sum(1 for r in kid if len(r[2]) >= 2 and r[2][1] <= 5.0)
    print(f"kidnaps: {len(kid)} runs, recovered within 5 s in {back}")
    if rows:
        rmse = sorted(r[4]["position_rmse"] for r in rows)
        head = sorted(r[4]["heading_rmse"] for r in rows)
        print(f"position RMSE median {rmse[len(rmse) // 2]:.3f} m (max {rmse[-1]:.3f}); "
              f"heading RMSE median {head[len(head) // 2]:.3f}° (max {head[-1]:.3f})")
        horizontal = sorted(r[4]["horizontal"] for r in rows)
        vertical = sorted(r[4]["vertical"] for r in rows)
        print(f"of which horizontal median {horizontal[len(horizontal) // 2]:.3f} m, "
              f"vertical median {vertical[len(vertical) // 2]:.3f} m")
        fp = sorted(r[4]["fitted_position"] for r in rows)
        fh = sorted(r[4]["fitted_heading"] for r in rows)
        print(f"with the map frame fitted to the whole mapping run (diagnostic): position RMSE "
              f"median {fp[len(fp) // 2]:.3f} m (max {fp[-1]:.3f}); heading RMSE median "
              f"{fh[len(fh) // 2]:.3f}° (max {fh[-1]:.3f})")
    return 0 if wrong == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
