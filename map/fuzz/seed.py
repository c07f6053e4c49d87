#!/usr/bin/env python3
"""Builds the `map_decode` seed corpus from a real site map: the file itself, cuts of it, and
smaller valid maps made from it (keyframes without their points, as a map whose keyframes
released them holds; a few intensity cells; no keyframes at all), so that mutations start
from every section at sizes the fuzzer runs quickly.

    glintd sim warehouse --seconds 5 --seed 3 --out /tmp/fz
    glintd replay /tmp/fz/scan.pcap --no-publish --save-map /tmp/fz/site.glintmap
    python3 map/fuzz/seed.py /tmp/fz/site.glintmap
"""
import os
import struct
import sys
import zlib

HEADER, TRAILER, POSE, CELL = 168, 12, 56, 18
EDGE = 4 + 4 + POSE + 21 * 8 + 1
KEYFRAME_FIXED = POSE + 8 + POSE + 12

here = os.path.dirname(os.path.abspath(__file__))
out = os.path.join(here, "corpus", "map_decode")
os.makedirs(out, exist_ok=True)
data = open(sys.argv[1] if len(sys.argv) > 1 else "/tmp/fz/site.glintmap", "rb").read()
assert data[:8] == b"GLINTMAP", "not a glintmap"


def u32(at):
    return struct.unpack_from("<I", data, at)[0]


def u64(at):
    return struct.unpack_from("<Q", data, at)[0]


def seal(content):
    content = bytearray(content)
    content[12:20] = struct.pack("<Q", len(content) + TRAILER)
    content += struct.pack("<Q", len(content))
    return bytes(content + struct.pack("<I", zlib.crc32(content)))


# The sections of the real map.
keyframes, cells, edges = u64(112), u64(128), u64(136)
sectors, rings, model = u32(156), u32(160), u32(164)
descriptor = sectors * rings * 4
at = HEADER + model
frames = []  # (pose, time, odom pose, descriptor) of each keyframe, points left out
for _ in range(keyframes):
    fixed = data[at : at + KEYFRAME_FIXED]
    n = sum(struct.unpack_from("<3I", fixed, POSE + 8 + POSE))
    at += KEYFRAME_FIXED
    edge_planes = struct.unpack_from("<2I", fixed, POSE + 8 + POSE)
    at += 12 * sum(edge_planes) + 16 * (n - sum(edge_planes))
    frames.append((fixed[: KEYFRAME_FIXED - 12], data[at : at + descriptor]))
    at += descriptor
cell_bytes = [data[at + i * CELL : at + (i + 1) * CELL] for i in range(cells)]
at += cells * CELL
edge_bytes = [data[at + i * EDGE : at + (i + 1) * EDGE] for i in range(edges)]
assert at + edges * EDGE + TRAILER == len(data), "the sections do not add up"


def small_map(n_keyframes, n_cells):
    """The real map cut to its first keyframes (without points), first cells, and the edges
    between those keyframes; the extent is then the keyframes' positions, as f32."""
    kept = frames[:n_keyframes]
    kept_edges = [e for e in edge_bytes if max(struct.unpack_from("<2I", e)) < n_keyframes]
    header = bytearray(data[:HEADER])
    if kept:
        xyz = [struct.unpack_from("<3d", f) for f, _ in kept]
        f32 = lambda v: struct.unpack("<f", struct.pack("<f", v))[0]
        lo = [min(f32(p[a]) for p in xyz) for a in range(3)]
        hi = [max(f32(p[a]) for p in xyz) for a in range(3)]
        header[20:24] = struct.pack("<I", 1)
        header[88:112] = struct.pack("<6f", *lo, *hi)
    else:
        header[20:24] = struct.pack("<I", 0)
        header[88:112] = bytes(24)
        header[156:164] = bytes(8)
    header[112:144] = struct.pack("<4Q", len(kept), 0, n_cells, len(kept_edges))
    body = data[HEADER : HEADER + model]
    for fixed, grid in kept:
        body += fixed + bytes(12) + grid
    body += b"".join(cell_bytes[:n_cells]) + b"".join(kept_edges)
    return seal(bytes(header) + body)


seeds = {
    "real": data,
    "keyframes_no_points": small_map(len(frames), 0),
    "two_keyframes": small_map(2, 16),
    "one_keyframe": small_map(1, 0),
    "cells_only": small_map(0, 64),
    "empty": small_map(0, 0),
}
for cut in [HEADER - 1, HEADER, HEADER + model, 1024, 4096, 16384, 65536, len(data) // 2, len(data) - 1]:
    seeds[f"cut{cut}"] = data[:cut]
for name, bytes_ in seeds.items():
    open(os.path.join(out, name), "wb").write(bytes_)
print(f"{len(seeds)} seeds in {out}: {len(frames)} keyframes, {cells} cells, {edges} edges")
