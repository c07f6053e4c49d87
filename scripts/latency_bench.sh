#!/usr/bin/env bash
# Live latency benchmark: `glintd run` receives a simulated VLP-16 streamed over UDP on localhost at
# real-time pace (the simulator's own process), and reports the latency from each sweep's last
# packet to its published pose (median and p99), sweeps processed and dropped.
#
#   bash scripts/latency_bench.sh [SCENARIO] [SECONDS] [SEED]      # defaults: warehouse 60 3
#
# Not run by CI (it takes SECONDS of wall time). The replay equivalent:
#   glintd replay CAPTURE --pace realtime     (prints the same latency figures)
set -euo pipefail
cd "$(dirname "$0")/.."
scenario=${1:-warehouse}
seconds=${2:-60}
seed=${3:-3}
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
GLINT_LOG=info NO_COLOR=1 "$glintd" run --config "$work/glintd.toml" 2> "$work/log" &
daemon=$!
until grep -q ready "$work/log"; do sleep 0.1; done
"$glintd" sim "$scenario" --seconds "$seconds" --seed "$seed" --udp 127.0.0.1 \
    --data-port "$data_port" --position-port "$position_port" > /dev/null 2>&1
sleep 0.5
kill -TERM "$daemon"
wait "$daemon"
echo "glintd run, $scenario seed $seed, $seconds s at real-time pace over UDP:"
grep stopped "$work/log" | sed 's/.*INFO //'
