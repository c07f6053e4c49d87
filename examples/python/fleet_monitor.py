#!/usr/bin/env python3
"""Fleet-side monitor: every robot's latest pose and status from Glint's fleet link.

Subscribes to glint/<site>/*/{odom,map,status} over Zenoh (PyPI eclipse-zenoh==1.10.2, the
version glintd's bridge is built with) and prints one line per sample, or with --table the
latest of each robot once a second. The payloads are the shared-memory layouts of
ipc/README.md (glint::PoseV1, 424 bytes; glint::StatusV1, 80 bytes), little-endian; the
attachment names the type and version ("type=glint::PoseV1;version=1").

    python3 fleet_monitor.py --connect tls/fleet-router:7447 --ca ca.pem --cert me.pem --key me.key
    python3 fleet_monitor.py --connect tcp/127.0.0.1:7447 --insecure --count 10

--dump FILE writes "<key> <sequence> <hex bytes>" per sample (for tests comparing transports).
"""

import argparse
import json
import struct
import sys
import threading
import time

import zenoh

# glint::PoseV1: sequence, timestamp_ns, position[3], orientation xyzw[4], linear_velocity[3],
# angular_velocity[3], covariance[36], quality, frame, status, padding.
POSE = struct.Struct("<QQ3d4d3d3d36dfII4x")
# glint::StatusV1: sequence, timestamp_ns, sweeps processed/dropped, packets received/
# dropped/malformed, sweep rate, packet rate, latency median/p99, flags, padding.
STATUS = struct.Struct("<QQQQQQQffffI4x")
TYPES = {"glint::PoseV1": POSE, "glint::StatusV1": STATUS}
FRAMES = {0: "odom", 1: "map"}


def attachment_type(sample):
    """The payload type named by the attachment, or None."""
    if sample.attachment is None:
        return None
    fields = dict(
        kv.split("=", 1) for kv in sample.attachment.to_string().split(";") if "=" in kv
    )
    return fields.get("type")


def describe(kind, values):
    if kind == "glint::PoseV1":
        seq, stamp = values[0], values[1]
        x, y, z = values[2:5]
        qx, qy, qz, qw = values[5:9]
        quality, frame, status = values[-3], values[-2], values[-1]
        return (
            f"pose {FRAMES.get(frame, frame)} #{seq} t={stamp / 1e9:.3f} "
            f"xyz=({x:.3f}, {y:.3f}, {z:.3f}) q=({qx:.4f}, {qy:.4f}, {qz:.4f}, {qw:.4f}) "
            f"quality={quality:.2f} status=0x{status:x}"
        )
    seq, stamp, processed, dropped, received, lost, malformed = values[:7]
    rate, _packets, median, p99, flags = values[7:]
    return (
        f"status #{seq} t={stamp / 1e9:.3f} sweeps={processed} dropped={dropped} "
        f"packets={received} lost={lost} rate={rate:.1f}Hz latency={median:.1f}/{p99:.1f}ms "
        f"flags=0x{flags:x}"
    )


def config(args):
    conf = zenoh.Config()
    mode = "client" if args.client else "peer"
    conf.insert_json5("mode", json.dumps(mode))
    conf.insert_json5("connect/endpoints", json.dumps(args.connect))
    conf.insert_json5("listen/endpoints", json.dumps(args.listen))
    if args.connect or args.listen:
        conf.insert_json5("scouting/multicast/enabled", "false")
    if args.ca:
        tls = {"root_ca_certificate": args.ca, "enable_mtls": bool(args.cert)}
        if args.cert:
            tls.update(
                connect_certificate=args.cert,
                connect_private_key=args.key,
                listen_certificate=args.cert,
                listen_private_key=args.key,
            )
        conf.insert_json5("transport/link/tls", json.dumps(tls))
        conf.insert_json5("transport/link/protocols", json.dumps(["tls"]))
    elif not args.insecure:
        sys.exit("fleet_monitor: give --ca (TLS) or --insecure for plain TCP")
    return conf


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--site", default="site")
    parser.add_argument("--robot", default="*", help="one robot, or * for all")
    parser.add_argument("--connect", action="append", default=[], help="Zenoh endpoint")
    parser.add_argument("--listen", action="append", default=[], help="Zenoh endpoint")
    parser.add_argument("--client", action="store_true", help="client mode (through a router)")
    parser.add_argument("--ca", help="root CA certificate (PEM): TLS")
    parser.add_argument("--cert", help="client certificate (PEM): mutual TLS")
    parser.add_argument("--key", help="the client certificate's private key (PEM)")
    parser.add_argument("--insecure", action="store_true", help="plain TCP")
    parser.add_argument("--count", type=int, help="exit after this many samples")
    parser.add_argument("--timeout", type=float, help="exit after this many seconds")
    parser.add_argument("--idle", type=float, help="exit this many seconds after the last sample")
    parser.add_argument("--table", action="store_true", help="latest per robot, once a second")
    parser.add_argument("--dump", help="write <key> <sequence> <hex> per sample")
    args = parser.parse_args()
    zenoh.init_log_from_env_or("error")

    done = threading.Event()
    lock = threading.Lock()
    latest = {}
    received = [0]
    last = [None]
    dump = open(args.dump, "w") if args.dump else None

    def on_sample(sample):
        kind = attachment_type(sample)
        layout = TYPES.get(kind)
        raw = sample.payload.to_bytes()
        key = str(sample.key_expr)
        if layout is None or len(raw) != layout.size:
            print(f"{key}: unknown payload {kind!r} of {len(raw)} bytes", file=sys.stderr)
            return
        values = layout.unpack(raw)
        with lock:
            if done.is_set():
                return
            latest[key] = describe(kind, values)
            if dump:
                dump.write(f"{key} {values[0]} {raw.hex()}\n")
            if not args.table:
                print(f"{key} {latest[key]}", flush=True)
            received[0] += 1
            last[0] = time.monotonic()
            if args.count is not None and received[0] >= args.count:
                done.set()

    with zenoh.open(config(args)) as session:
        key = f"glint/{args.site}/{args.robot}/*"
        subscriber = session.declare_subscriber(key, on_sample)
        print(f"subscribed to {key}", flush=True)
        started = time.monotonic()
        while not done.wait(1.0 if args.table else 0.05):
            if args.table:
                with lock:
                    for k in sorted(latest):
                        print(f"{k} {latest[k]}")
                print(flush=True)
            now = time.monotonic()
            if args.timeout is not None and now - started >= args.timeout:
                break
            with lock:
                quiet = last[0] is not None and args.idle is not None and now - last[0] >= args.idle
            if quiet:
                break
        subscriber.undeclare()
    if dump:
        dump.close()
    if args.count is not None and received[0] < args.count:
        sys.exit(f"fleet_monitor: received {received[0]} of {args.count} samples")


if __name__ == "__main__":
    main()
