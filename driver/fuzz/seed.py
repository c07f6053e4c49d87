#!/usr/bin/env python3
"""Builds the fuzz seed corpora from the real captures in ../shared/data (not copied into the
repository): real data payloads for `packet`, a short real capture prefix for `pcap`.

    python3 driver/fuzz/seed.py && cd driver/fuzz && cargo fuzz run packet corpus/packet
"""
import os
import struct

here = os.path.dirname(os.path.abspath(__file__))
src = os.path.join(here, "..", "..", "..", "shared", "data", "vlp16_real_short.pcap")
data = open(src, "rb").read()
os.makedirs(os.path.join(here, "corpus", "packet"), exist_ok=True)
os.makedirs(os.path.join(here, "corpus", "pcap"), exist_ok=True)
off, n = 24, 0
while off + 16 <= len(data) and n < 16:
    caplen = struct.unpack("<I", data[off + 8 : off + 12])[0]
    payload = data[off + 16 + 42 : off + 16 + caplen]
    off += 16 + caplen
    if len(payload) in (1206, 512):
        open(os.path.join(here, "corpus", "packet", f"real{n}"), "wb").write(payload)
        n += 1
open(os.path.join(here, "corpus", "pcap", "real_prefix.pcap"), "wb").write(data[: 24 + 4 * (16 + 1248)])
print(f"{n} packet seeds, 1 capture seed")
