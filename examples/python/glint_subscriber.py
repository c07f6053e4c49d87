#!/usr/bin/env python3
"""Print Glint poses from shared memory: a Python consumer of glint/<domain>/<stream>.

Owns the Python mirror of Glint's `Pose` (ipc/README.md is the contract; this file must follow
its byte-layout table) and a minimal subscriber loop: open the pose service and its event
service (never create them: the daemon does, with the settings consumers rely on), sleep on the
event service, copy each pose out, print it as one line, and release everything before exit.

    pip install -r requirements.txt          # iceoryx2==0.10.0, exactly
    python3 glint_subscriber.py --domain agv7 --count 10 --timeout 5

Output, one line per pose:
    sequence timestamp_s x y z qx qy qz qw flags

Exit status: 0 after --count poses (or at --timeout when --count is 0), 1 when --timeout passed
first, 2 on bad arguments or when the service does not exist (daemon not running, other domain,
or another iceoryx2 root path) or cannot be opened, 128 + signal number after SIGINT or SIGTERM
(ports and node are released in every case).
"""

from __future__ import annotations

import argparse
import ctypes
import logging
import re
import signal
import sys
import time

import iceoryx2 as iox2

ICEORYX2_VERSION = "0.10.0"


class Pose(ctypes.Structure):
    """`glint::PoseV1`: 424 bytes, alignment 8, native byte order. See ipc/README.md."""

    _fields_ = [
        ("sequence", ctypes.c_uint64),  # 0
        ("timestamp_ns", ctypes.c_uint64),  # 8: instant described, ns since the Unix epoch
        ("position", ctypes.c_double * 3),  # 16: m, base_link in `frame`
        ("orientation", ctypes.c_double * 4),  # 40: Hamilton quaternion x, y, z, w
        ("linear_velocity", ctypes.c_double * 3),  # 72: m/s, body frame
        ("angular_velocity", ctypes.c_double * 3),  # 96: rad/s, body frame
        ("covariance", ctypes.c_double * 36),  # 120: 6x6 row-major [x y z roll pitch yaw]
        ("quality", ctypes.c_float),  # 408: 0..1
        ("frame", ctypes.c_uint32),  # 412: 0 odom, 1 map
        ("status", ctypes.c_uint32),  # 416: flag bits below
        ("_pad0", ctypes.c_uint32),  # 420: padding, always 0
    ]

    @staticmethod
    def type_name() -> str:
        """The iceoryx2 type name; iceoryx2 matches services by this name and the size."""
        return "glint::PoseV1"


# Fail at start, not with garbled numbers, if this mirror ever drifts from the contract.
assert ctypes.sizeof(Pose) == 424 and ctypes.alignment(Pose) == 8, "Pose layout drifted"
assert (Pose.covariance.offset, Pose.quality.offset, Pose._pad0.offset) == (120, 408, 420)

FLAGS = [
    (1 << 0, "INITIALISING"),
    (1 << 1, "TRACKING"),
    (1 << 2, "DEGENERATE"),
    (1 << 3, "LOST"),
    (1 << 4, "LOOP_CLOSED"),
    (1 << 5, "PREDICTED"),
    (1 << 6, "SENSOR_SILENT"),
    (1 << 7, "RELOCALISING"),
    (1 << 8, "FOREIGN_SENSOR"),
]


def flag_names(bits: int) -> str:
    """`TRACKING|PREDICTED`; unknown (reserved) bits in hex; `-` for none."""
    names = [name for bit, name in FLAGS if bits & bit]
    unknown = bits & ~((1 << len(FLAGS)) - 1)
    if unknown:
        names.append(hex(unknown))
    return "|".join(names) or "-"


def format_pose(pose: Pose) -> str:
    seconds, nanos = divmod(pose.timestamp_ns, 1_000_000_000)
    x, y, z = pose.position
    qx, qy, qz, qw = pose.orientation
    return (
        f"{pose.sequence} {seconds}.{nanos:09d} "
        f"{x:.6f} {y:.6f} {z:.6f} {qx:.6f} {qy:.6f} {qz:.6f} {qw:.6f} "
        f"{flag_names(pose.status)}"
    )


def copy_out(sample: iox2.Sample) -> Pose:
    """Copy the payload out of shared memory, then release the sample at once: a subscriber may
    hold only 2 samples, and no view into the sample may outlive it."""
    try:
        return Pose.from_buffer_copy(ctypes.string_at(sample.payload_ptr, ctypes.sizeof(Pose)))
    finally:
        sample.delete()


def parse_args() -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--domain", required=True, help="the daemon's domain: glint/<domain>/...")
    parser.add_argument(
        "--stream",
        choices=["odom", "map", "predicted"],
        default="odom",
        help="which pose stream (default odom)",
    )
    parser.add_argument(
        "--count", type=int, default=10, help="exit after N poses; 0 = until --timeout (default 10)"
    )
    parser.add_argument(
        "--timeout", type=float, default=10.0, help="exit after S seconds (default 10)"
    )
    args = parser.parse_args()
    # The daemon accepts only such domains (glint_ipc::Domain); say so rather than "not found".
    if not re.fullmatch(r"[A-Za-z0-9_-]{1,64}", args.domain):
        parser.error("--domain must be 1 to 64 characters from A-Z, a-z, 0-9, '_' and '-'")
    if args.count < 0 or not args.timeout > 0:
        parser.error("--count must be >= 0 and --timeout > 0")
    return args


class StopFlag:
    """Set by SIGINT/SIGTERM. A flag rather than Python's KeyboardInterrupt, so the signal can
    never land in the middle of the cleanup and leave a dead node behind."""

    def __init__(self) -> None:
        self.signal: int | None = None

    def set(self, signum: int, _frame: object) -> None:
        self.signal = signum


def receive(
    subscriber: iox2.Subscriber, listener: iox2.Listener, count: int, timeout: float, stop: StopFlag
) -> int:
    """Print poses until `count` (0: no limit) arrived, `timeout` passed or a stop signal came;
    return how many arrived."""
    deadline = time.monotonic() + timeout
    received = 0
    while stop.signal is None:
        # Drain everything queued: one notification may stand for several poses.
        while count == 0 or received < count:
            sample = subscriber.receive()
            if sample is None:
                break
            print(format_pose(copy_out(sample)), flush=True)
            received += 1
        if count and received >= count:
            break
        remaining = deadline - time.monotonic()
        if remaining <= 0:
            break
        # Sleep until the daemon notifies (after every send). Capped so a signal is seen
        # promptly even if it does not interrupt the wait.
        try:
            listener.timed_wait(iox2.Duration.from_secs_f64(min(remaining, 0.5)))
        except iox2.ListenerWaitError as error:
            # A signal interrupts the wait; the loop condition decides whether to stop.
            if "InterruptSignal" not in str(error):
                raise
    return received


def main() -> int:
    args = parse_args()
    # iceoryx2 filters by its own level (IOX2_LOG_LEVEL, default errors only) and then hands the
    # records to Python's `logging`, which must let them through.
    logging.basicConfig(level=logging.DEBUG, format="%(levelname)s %(name)s: %(message)s")
    iox2.set_log_level_from_env_or(iox2.LogLevel.Error)
    service_name = f"glint/{args.domain}/{args.stream}"

    # Everything lives in this function's locals and is released in `finally`: objects left in
    # module-level variables are never dropped at exit and leave a dead node behind.
    stop = StopFlag()
    signal.signal(signal.SIGINT, stop.set)
    signal.signal(signal.SIGTERM, stop.set)

    node = subscriber = listener = None
    try:
        node = (
            iox2.NodeBuilder.new()
            .name(iox2.NodeName.new(f"glint-python/{args.domain}/{args.stream}"))
            # The signals are ours (StopFlag); iceoryx2 must not handle them itself.
            .signal_handling_mode(iox2.SignalHandlingMode.Disabled)
            .create(iox2.ServiceType.Ipc)
        )
        try:
            service = (
                node.service_builder(iox2.ServiceName.new(service_name))
                .publish_subscribe(Pose)
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
        subscriber = service.subscriber_builder().create()
        listener = event.listener_builder().create()
        del service, event  # the ports keep what they need

        received = receive(subscriber, listener, args.count, args.timeout, stop)
        if stop.signal is not None:
            return 128 + stop.signal
        if args.count and received < args.count:
            print(
                f"timed out after {args.timeout} s with {received} of {args.count} poses",
                file=sys.stderr,
            )
            return 1
        return 0
    finally:
        if listener is not None:
            listener.delete()
        if subscriber is not None:
            subscriber.delete()
        del node


if __name__ == "__main__":
    sys.exit(main())
