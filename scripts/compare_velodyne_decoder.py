#!/usr/bin/env python3
"""Compare `glintd decode` with velodyne-decoder (PyPI) on a VLP-16 capture.

velodyne-decoder trusts the product-id byte, so captures whose byte is wrong (the real ones in
shared/data say 0x21) are copied with byte 1205 of every 1206-byte data payload set to 0x22
first. Both decoders list returns in firing order; the script compares them one to one.

    pip install velodyne-decoder
    python3 scripts/compare_velodyne_decoder.py CAPTURE [--glintd target/release/glintd]

Not part of the test suite (it needs PyPI); it prints the largest differences.
"""
import argparse
import csv
import os
import struct
import subprocess
import sys
import tempfile

import numpy as np
import velodyne_decoder as vd


def patched_copy(src, dst):
    data = bytearray(open(src, "rb").read())
    magic = struct.unpack("<I", data[:4])[0]
    if magic not in (0xA1B2C3D4, 0xA1B23C4D):
        sys.exit("only little-endian classic pcap is patched here")
    off = 24
    while off + 16 <= len(data):
        caplen = struct.unpack("<I", data[off + 8 : off + 12])[0]
        start = off + 16
        frame = data[start : start + caplen]
        # Ethernet + IPv4 (any IHL) + UDP
        if len(frame) > 14 and frame[12:14] == b"\x08\x00":
            ihl = (frame[14] & 0x0F) * 4
            udp = 14 + ihl
            payload = udp + 8
            if caplen - payload == 1206:
                data[start + payload + 1205] = 0x22
        off = start + caplen
    open(dst, "wb").write(data)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("capture")
    ap.add_argument("--glintd", default="target/release/glintd")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        fixed = os.path.join(tmp, "fixed.pcap")
        patched_copy(args.capture, fixed)
        cfg = vd.Config(model=vd.Model.VLP16, min_range=0.0, max_range=1000.0)
        theirs = np.concatenate([c for _, c in vd.read_pcap(fixed, cfg, as_pcl_structs=True)])
        out = os.path.join(tmp, "glint.csv")
        subprocess.run([args.glintd, "decode", args.capture, "--out", out], check=True)
        with open(out) as f:
            rows = list(csv.DictReader(f))
    ours_xyz = np.array([[float(r["x"]), float(r["y"]), float(r["z"])] for r in rows])
    ours_i = np.array([int(r["reflectivity"]) for r in rows])
    ours_ring = np.array([int(r["ring"]) for r in rows])
    print(f"returns: glint {len(rows)}, velodyne-decoder {len(theirs)}")
    n = min(len(rows), len(theirs))
    theirs_xyz = np.stack([theirs["x"], theirs["y"], theirs["z"]], axis=1)[:n]
    d = np.linalg.norm(ours_xyz[:n] - theirs_xyz, axis=1)
    print(f"position difference: median {np.median(d)*1e3:.3f} mm, p99 {np.percentile(d, 99)*1e3:.3f} mm, max {d.max()*1e3:.3f} mm")
    print(f"reflectivity equal: {np.mean(ours_i[:n] == theirs['intensity'][:n]) * 100:.2f} %")
    print(f"ring equal: {np.mean(ours_ring[:n] == theirs['ring'][:n]) * 100:.2f} %")


if __name__ == "__main__":
    main()
