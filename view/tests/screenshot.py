#!/usr/bin/env python3
"""Opens a page in headless Chromium through ChromeDriver (W3C WebDriver over HTTP, standard
library only), waits for it to render, and saves a PNG screenshot.

    python3 view/tests/screenshot.py URL OUT.png [--wait S] [--size WxH]

Chromium runs with software WebGL (SwiftShader), without background networking, in a fresh
profile: what a machine without a GPU and with a closed network needs.
"""

import argparse
import base64
import json
import os
import signal
import shutil
import socket
import subprocess
import sys
import tempfile
import time
import urllib.request


def free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def call(base, method, path, body=None, timeout=60):
    data = json.dumps(body).encode() if body is not None else None
    req = urllib.request.Request(base + path, data=data, method=method,
                                 headers={"Content-Type": "application/json"})
    with urllib.request.urlopen(req, timeout=timeout) as r:
        return json.loads(r.read().decode())


def screenshot(url, out, wait=20.0, size=(1280, 800)):
    """Saves a PNG of `url` as headless Chromium renders it after `wait` seconds."""
    width, height = size
    chromium = shutil.which("chromium") or "/usr/bin/chromium"
    driver = shutil.which("chromedriver") or "/usr/bin/chromedriver"
    port = free_port()
    profile = tempfile.mkdtemp(prefix="glint-chromium-")
    # A session of its own, so that Chromium goes with ChromeDriver whatever happens.
    proc = subprocess.Popen([driver, f"--port={port}"], stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL, start_new_session=True)
    base = f"http://127.0.0.1:{port}"
    try:
        for _ in range(100):
            try:
                call(base, "GET", "/status", timeout=2)
                break
            except OSError:
                time.sleep(0.1)
        caps = {"capabilities": {"alwaysMatch": {
            "browserName": "chrome",
            "goog:chromeOptions": {
                "binary": chromium,
                "args": [
                    "--headless=new", "--no-sandbox", "--use-angle=swiftshader",
                    "--enable-unsafe-swiftshader", "--ignore-gpu-blocklist",
                    "--disable-background-networking", "--disable-component-update",
                    "--disable-sync", "--disable-quic", "--no-first-run", "--disable-breakpad",
                    "--disable-crash-reporter",
                    f"--user-data-dir={profile}", f"--window-size={width},{height}",
                ],
            },
        }}}
        session = call(base, "POST", "/session", caps)["value"]["sessionId"]
        try:
            call(base, "POST", f"/session/{session}/url", {"url": url})
            time.sleep(wait)
            # Software WebGL on a busy machine can hold the page for a while.
            png = call(base, "GET", f"/session/{session}/screenshot", timeout=180)["value"]
            with open(out, "wb") as f:
                f.write(base64.b64decode(png))
        finally:
            call(base, "DELETE", f"/session/{session}")
    finally:
        try:
            os.killpg(proc.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        proc.wait(timeout=10)
        shutil.rmtree(profile, ignore_errors=True)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("url")
    ap.add_argument("out")
    ap.add_argument("--wait", type=float, default=20.0, help="seconds to let the page render")
    ap.add_argument("--size", default="1280x800")
    args = ap.parse_args()
    size = tuple(int(v) for v in args.size.split("x"))
    screenshot(args.url, args.out, args.wait, size)
    return 0


if __name__ == "__main__":
    sys.exit(main())
