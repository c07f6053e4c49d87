#!/usr/bin/env python3
"""Shows a glint-view recording in rerun's web viewer, in headless Chromium, beside an empty
viewer, and prints what tells the two apart, one `name value` per line:

    python3 view/tests/browser.py RECORDING.rrd OUT_DIR

- `differing`: the fraction of pixels that differ between the two screenshots;
- `ramp_pixels_recording`, `ramp_pixels_empty`: pixels in the colours glint-view draws points in
  (the reflectivity ramp's stops and the feature classes, see view/src/colour.rs).

Both viewers are served by `rerun --serve-web` (rerun-sdk==0.36.3) on loopback ports chosen
here, with a configuration directory of their own in which analytics are disabled first. The
screenshots are left in OUT_DIR (recording.png, empty.png).
"""

import os
import signal
import socket
import subprocess
import sys
import tempfile
import time
import urllib.parse
from pathlib import Path

from PIL import Image

from screenshot import free_port, screenshot

# Colours glint-view gives points (view/src/colour.rs): the ramp's stops and the classes.
POINT_COLOURS = [
    (30, 20, 90), (40, 90, 160), (30, 160, 140), (140, 210, 70), (250, 235, 40),
    (230, 60, 50), (70, 130, 230), (250, 170, 30),
]
SIZE = (1280, 800)
RENDER_S = 25.0


def wait_for_port(port, proc, timeout=60.0):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            raise RuntimeError(f"rerun exited with {proc.returncode} before listening on {port}")
        with socket.socket() as s:
            if s.connect_ex(("127.0.0.1", port)) == 0:
                return
        time.sleep(0.2)
    raise RuntimeError(f"rerun did not listen on {port} within {timeout} s")


def serve_and_shoot(env, rrd, out):
    """Serves `rrd` (or nothing, for an empty viewer) and screenshots the web viewer."""
    grpc, web = free_port(), free_port()
    cmd = ["rerun", "--serve-web", "--bind", "127.0.0.1", "--port", str(grpc),
           "--web-viewer-port", str(web)]
    if rrd is not None:
        cmd.append(str(rrd))
    log = open(Path(out).with_suffix(".log"), "w")
    # `rerun` is a Python launcher that starts the viewer's binary as its child: a session of its
    # own lets both be stopped together.
    proc = subprocess.Popen(cmd, env=env, stdout=log, stderr=subprocess.STDOUT,
                            start_new_session=True)
    try:
        wait_for_port(web, proc)
        wait_for_port(grpc, proc)
        source = urllib.parse.quote(f"rerun+http://127.0.0.1:{grpc}/proxy", safe="")
        screenshot(f"http://127.0.0.1:{web}/?url={source}", out, RENDER_S, SIZE)
    finally:
        stop_group(proc)
        log.close()


def stop_group(proc):
    """Stops a process and every process of its session, the launched viewer included."""
    for sig in (signal.SIGTERM, signal.SIGKILL):
        try:
            os.killpg(proc.pid, sig)
        except ProcessLookupError:
            break
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            continue
        time.sleep(0.5)


def point_pixels(image):
    """Pixels within a few levels of a colour glint-view draws points in."""
    count = 0
    for r, g, b in image.getdata():
        for pr, pg, pb in POINT_COLOURS:
            if abs(r - pr) <= 12 and abs(g - pg) <= 12 and abs(b - pb) <= 12:
                count += 1
                break
    return count


def main(rrd, out_dir):
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="glint-rerun-config-") as config:
        env = dict(os.environ, XDG_CONFIG_HOME=config)
        # Nothing may phone home, and the first run's analytics notice must not wait for input.
        subprocess.run(["rerun", "analytics", "disable"], env=env, check=True,
                       stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        serve_and_shoot(env, rrd, out_dir / "recording.png")
        serve_and_shoot(env, None, out_dir / "empty.png")
    recording = Image.open(out_dir / "recording.png").convert("RGB")
    empty = Image.open(out_dir / "empty.png").convert("RGB")
    if recording.size != empty.size:
        print(f"sizes differ: {recording.size} vs {empty.size}", file=sys.stderr)
        return 1
    differing = sum(
        1 for a, b in zip(recording.getdata(), empty.getdata())
        if max(abs(x - y) for x, y in zip(a, b)) > 24
    )
    total = recording.size[0] * recording.size[1]
    print(f"differing {differing / total:.4f}")
    print(f"ramp_pixels_recording {point_pixels(recording)}")
    print(f"ramp_pixels_empty {point_pixels(empty)}")
    return 0


if __name__ == "__main__":
    if len(sys.argv) != 3:
        print(__doc__, file=sys.stderr)
        sys.exit(2)
    sys.exit(main(sys.argv[1], sys.argv[2]))
