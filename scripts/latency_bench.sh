#!/usr/bin/env bash
# Live latency benchmark: `glintd run` receives a simulated VLP-16 streamed over UDP on localhost at
# real-time pace (the simulator's own process), and reports the latency from each sweep's last
# packet to its published pose (median and p99), sweeps processed and dropped.
#
#   bash scripts/latency_bench.sh [SCENARIO] [SECONDS] [SEED] [stress] [pinned] [viewer|stalled]
#                                                                # defaults: warehouse 60 3
#
# `stress` keeps a busy loop running on the last core the whole time, as the navigation stack
# would on the robot's computer; `pinned` pins the odometry thread to core 0 at real-time priority
# 40 (`[pipeline] odometry_cpu`, `odometry_priority`; the priority needs CAP_SYS_NICE, which root
# has, and is reported as refused otherwise). `viewer` runs `glint-view --save` on the domain the
# whole time (it reads every service and writes a recording); `stalled` starts it and stops it
# with SIGSTOP once it is attached, so its ports are held and never read.
#
# GLINTD=PATH times that binary instead of building this checkout's (to alternate an old and a
# new one). Not run by CI (it takes SECONDS of wall time). The replay equivalent:
#   glintd replay CAPTURE --pace realtime     (prints the same latency figures)
set -euo pipefail
cd "$(dirname "$0")/.."
scenario=${1:-warehouse}
seconds=${2:-60}
seed=${3:-3}
stress=
pinned=
consumer=
for flag in "${@:4}"; do
    case "$flag" in
        stress) stress=stress ;;
        pinned) pinned=pinned ;;
        viewer | stalled) consumer=$flag ;;
        *) echo "unknown option $flag" >&2; exit 2 ;;
    esac
done
if [ -z "${GLINTD:-}" ]; then
    cargo build --release -p glintd --quiet
fi
if [ -n "$consumer" ]; then
    cargo build --release -p glint-view --quiet
fi
glintd=${GLINTD:-target/release/glintd}
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
read -r data_port position_port < <(python3 -c 'import socket
s=[socket.socket(socket.AF_INET, socket.SOCK_DGRAM) for _ in range(2)]
[x.bind(("127.0.0.1", 0)) for x in s]
print(*[x.getsockname()[1] for x in s])')
cat > "$work/glintd.toml" <<TOML
[sensor]
address = "127.0.0.1"
data_port = $data_port
position_port = $position_port
[ipc]
domain = "latency-bench-$$"
TOML
if [ "$pinned" = pinned ]; then
    printf '[pipeline]\nodometry_cpu = 0\nodometry_priority = 40\n' >> "$work/glintd.toml"
fi
hog=
if [ "$stress" = stress ]; then
    last_core=$(( $(nproc) - 1 ))
    taskset -c "$last_core" python3 -c 'while True: pass' &
    hog=$!
fi
view=
trap 'for p in $hog $view; do kill -CONT "$p" 2>/dev/null; kill "$p" 2>/dev/null || true; done; rm -rf "$work"' EXIT
GLINT_LOG=info NO_COLOR=1 "$glintd" run --config "$work/glintd.toml" 2> "$work/log" &
daemon=$!
until grep -q ready "$work/log"; do sleep 0.1; done
if [ -n "$consumer" ]; then
    target/release/glint-view --domain "latency-bench-$$" --save "$work/view.rrd" 2> "$work/view.log" &
    view=$!
    # Attached once the services it looks for ten times a second are there.
    sleep 1.5
    if [ "$consumer" = stalled ]; then
        kill -STOP "$view"
    fi
fi
"$glintd" sim "$scenario" --seconds "$seconds" --seed "$seed" --udp 127.0.0.1 \
    --data-port "$data_port" --position-port "$position_port" > /dev/null 2>&1
sleep 0.5
kill -TERM "$daemon"
wait "$daemon"
if [ -n "$view" ]; then
    kill -CONT "$view" 2>/dev/null || true
    kill -TERM "$view"
    wait "$view" || true
fi
echo "glintd run, $scenario seed $seed, $seconds s at real-time pace over UDP${stress:+, a busy loop on the last core}${pinned:+, odometry pinned to core 0 at SCHED_FIFO 40}${consumer:+, glint-view attached (${consumer})}:"
grep -E "pinned to a core|real-time priority" "$work/log" | sed 's/.*\(INFO\|WARN\) //' || true
grep stopped "$work/log" | sed 's/.*INFO //'
if [ -n "$view" ]; then
    grep "logged" "$work/view.log" || echo "glint-view logged nothing"
fi
