#!/usr/bin/env bash
# Live latency benchmark: `glintd run` receives a simulated VLP-16 streamed over UDP on localhost at
# real-time pace (the simulator's own process), and reports the latency from each sweep's last
# packet to its published pose (median and p99), sweeps processed and dropped.
#
#   bash scripts/latency_bench.sh [SCENARIO] [SECONDS] [SEED] [stress] [pinned]
#                                                                # defaults: warehouse 60 3
#
# `stress` keeps a busy loop running on the last core the whole time, as the navigation stack
# would on the robot's computer; `pinned` pins the odometry thread to core 0 at real-time priority
# 40 (`[pipeline] odometry_cpu`, `odometry_priority`; the priority needs CAP_SYS_NICE, which root
# has, and is reported as refused otherwise).
#
# Not run by CI (it takes SECONDS of wall time). The replay equivalent:
#   glintd replay CAPTURE --pace realtime     (prints the same latency figures)
set -euo pipefail
cd "$(dirname "$0")/.."
scenario=${1:-warehouse}
seconds=${2:-60}
seed=${3:-3}
stress=${4:-}
pinned=${5:-}
cargo build --release -p glintd --quiet
glintd=target/release/glintd
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
trap 'if [ -n "$hog" ]; then kill "$hog" 2>/dev/null || true; fi; rm -rf "$work"' EXIT
GLINT_LOG=info NO_COLOR=1 "$glintd" run --config "$work/glintd.toml" 2> "$work/log" &
daemon=$!
until grep -q ready "$work/log"; do sleep 0.1; done
"$glintd" sim "$scenario" --seconds "$seconds" --seed "$seed" --udp 127.0.0.1 \
    --data-port "$data_port" --position-port "$position_port" > /dev/null 2>&1
sleep 0.5
kill -TERM "$daemon"
wait "$daemon"
echo "glintd run, $scenario seed $seed, $seconds s at real-time pace over UDP${stress:+, a busy loop on the last core}${pinned:+, odometry pinned to core 0 at SCHED_FIFO 40}:"
grep -E "pinned to a core|real-time priority" "$work/log" | sed 's/.*\(INFO\|WARN\) //' || true
grep stopped "$work/log" | sed 's/.*INFO //'
