#!/usr/bin/env python3
"""Send glintd an initial-pose hint: roughly where the robot is in the saved site map.

Owns the Python mirror of Glint's `InitialPose` (ipc/README.md is the contract; this file must
follow its byte-layout table) and a one-shot sender: open glint/<domain>/initial_pose and its
event service (never create them: the daemon does, with the settings senders rely on), check
and send one hint, notify the daemon, keep the port open long enough for the daemon to take the
hint, and release everything before exit.

    pip install -r requirements.txt          # iceoryx2==0.10.0, exactly
    python3 glint_initial_pose.py --domain agv7 12.5 -3.0 1.57 --sigma 2

X and Y are metres in the map frame, YAW radians about its z axis (0 = facing +x), --sigma the
position's uncertainty in metres (default 0 = unknown). Prints one line when sent.

Exit status: 0 when sent, 1 when the hint could not be sent, 2 on bad arguments or an invalid
hint, or when the service does not exist (daemon not running, other domain, or another
iceoryx2 root path) or cannot be opened.
"""

from __future__ import annotations

import argparse
import ctypes
import logging
import math
import re
import sys
import time

import iceoryx2 as iox2

ICEORYX2_VERSION = "0.10.0"

# The daemon polls for hints at least every 100 ms; iceoryx2 keeps a hint for it only once it
# has connected to this sender, so the sender stays this long after sending (as Glint's own
# senders do: glint_ipc::settings::INITIAL_POSE_SENDER_LINGER).
LINGER_S = 0.5

FRAME_MAP = 1


class InitialPose(ctypes.Structure):
    """`glint::InitialPoseV1`: 80 bytes, alignment 8, native byte order. See ipc/README.md."""

    _fields_ = [
        ("timestamp_ns", ctypes.c_uint64),  # 0: when sent, ns since the Unix epoch
        ("position", ctypes.c_double * 3),  # 8: m, base_link in the map frame
        ("orientation", ctypes.c_double * 4),  # 32: Hamilton quaternion x, y, z, w
        ("position_sigma", ctypes.c_double),  # 64: m, 1 sigma; 0 = unknown
        ("frame", ctypes.c_uint32),  # 72: must be 1 (map)
        ("_pad0", ctypes.c_uint32),  # 76: padding, always 0
    ]

    @staticmethod
    def type_name() -> str:
        """The iceoryx2 type name; iceoryx2 matches services by this name and the size."""
        return "glint::InitialPoseV1"


# Fail at start, not with a hint the daemon misreads, if this mirror ever drifts from the contract.
assert ctypes.sizeof(InitialPose) == 80 and ctypes.alignment(InitialPose) == 8, "layout drifted"
assert (InitialPose.position_sigma.offset, InitialPose.frame.offset) == (64, 72)


def on_floor(x: float, y: float, yaw: float, sigma: float) -> InitialPose:
    """base_link at (x, y, 0) turned yaw about z: quaternion (0, 0, sin(yaw/2), cos(yaw/2))."""
    return InitialPose(
        timestamp_ns=time.time_ns(),
        position=(ctypes.c_double * 3)(x, y, 0.0),
        orientation=(ctypes.c_double * 4)(0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2)),
        position_sigma=sigma,
        frame=FRAME_MAP,
        _pad0=0,
    )


def why_invalid(hint: InitialPose) -> str | None:
    """The daemon's check (InitialPose::validate): it skips hints that fail it."""
    values = [*hint.position, *hint.orientation, hint.position_sigma]
    if not all(math.isfinite(v) for v in values):
        return "every number must be finite"
    norm = math.sqrt(sum(v * v for v in hint.orientation))
    if abs(norm - 1.0) > 1e-6:
        return f"the orientation has norm {norm}; a unit quaternion is required"
    if hint.position_sigma < 0:
        return "--sigma must be >= 0 (0 = unknown)"
    if hint.frame != FRAME_MAP:
        return "the frame must be map (1)"
    return None


def parse_args() -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--domain", required=True, help="the daemon's domain: glint/<domain>/...")
    parser.add_argument("x", type=float, help="x of base_link in the map frame, m")
    parser.add_argument("y", type=float, help="y of base_link in the map frame, m")
    parser.add_argument("yaw", type=float, help="heading about the map's z axis, rad")
    parser.add_argument(
        "--sigma", type=float, default=0.0, help="position uncertainty, m (default 0 = unknown)"
    )
    # argparse reads "-3.0" as a number, not an option, since no option looks like one.
    args = parser.parse_args()
    if not re.fullmatch(r"[A-Za-z0-9_-]{1,64}", args.domain):
        parser.error("--domain must be 1 to 64 characters from A-Z, a-z, 0-9, '_' and '-'")
    return args


def main() -> int:
    args = parse_args()
    hint = on_floor(args.x, args.y, args.yaw, args.sigma)
    reason = why_invalid(hint)
    if reason is not None:
        print(f"refusing to send the hint: {reason}", file=sys.stderr)
        return 2

    # iceoryx2 filters by its own level (IOX2_LOG_LEVEL, default errors only) and then hands the
    # records to Python's `logging`, which must let them through.
    logging.basicConfig(level=logging.DEBUG, format="%(levelname)s %(name)s: %(message)s")
    iox2.set_log_level_from_env_or(iox2.LogLevel.Error)
    service_name = f"glint/{args.domain}/initial_pose"

    # Everything lives in this function's locals and is released in `finally`: objects left in
    # module-level variables are never dropped at exit and leave a dead node behind.
    node = publisher = notifier = None
    try:
        node = (
            iox2.NodeBuilder.new()
            .name(iox2.NodeName.new(f"glint-python-initial-pose/{args.domain}"))
            .signal_handling_mode(iox2.SignalHandlingMode.Disabled)
            .create(iox2.ServiceType.Ipc)
        )
        try:
            service = (
                node.service_builder(iox2.ServiceName.new(service_name))
                .publish_subscribe(InitialPose)
                .open()
            )
            event = node.service_builder(iox2.ServiceName.new(service_name + "/event")).event().open()
        except (iox2.PublishSubscribeOpenError, iox2.EventOpenError) as error:
            if "DoesNotExist" in str(error):
                print(
                    f"{service_name} does not exist: is glintd running with domain "
                    f"{args.domain!r}, with the same iceoryx2 root path (/tmp/iceoryx2, /dev/shm)?",
                    file=sys.stderr,
                )
            else:
                print(
                    f"cannot open {service_name}: {error!r} (IncompatibleTypes: another payload "
                    f"version; VersionMismatch: not iceoryx2 {ICEORYX2_VERSION})",
                    file=sys.stderr,
                )
            return 2
        publisher = service.publisher_builder().create()
        notifier = event.notifier_builder().create()
        del service, event  # the ports keep what they need

        try:
            publisher.send_copy(hint)
            notifier.notify()
        except Exception as error:  # noqa: BLE001 - any iceoryx2 failure ends the one shot
            print(f"cannot send on {service_name}: {error!r}", file=sys.stderr)
            return 1
        time.sleep(LINGER_S)
        print(
            f"sent x={args.x} y={args.y} yaw={args.yaw} sigma={args.sigma} on {service_name}",
            flush=True,
        )
        return 0
    finally:
        if notifier is not None:
            notifier.delete()
        if publisher is not None:
            publisher.delete()
        del node


if __name__ == "__main__":
    sys.exit(main())
