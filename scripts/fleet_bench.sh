#!/usr/bin/env bash
# Fleet link figures on loopback (plain TCP; nothing leaves the machine):
#   - pose latency from the daemon's publish to a fleet subscriber (median, p99), measured by
#     fleet/examples/fleet_latency.rs against the same poses from shared memory;
#   - the bridge's CPU (share of one core) and RSS while a replay runs at the sensor's pace;
#   - the transfer time of a map (`glintd map fetch`), if MAP is given.
#
#   bash scripts/fleet_bench.sh [SECONDS] [MAP]          # default 60 s of simulated warehouse
#
# The last line holds every figure as key=value. Not run by CI.
set -euo pipefail
cd "$(dirname "$0")/.."
seconds=${1:-60}
map=${2:-}
cargo build --release --quiet -p glintd
cargo build --release --quiet -p glint-fleet --example fleet_latency
glintd=target/release/glintd
work=$(mktemp -d)
pids=()
trap 'kill "${pids[@]}" 2>/dev/null || true; rm -rf "$work"' EXIT
port=$(python3 -c 'import socket; s=socket.socket(); s.bind(("127.0.0.1",0)); print(s.getsockname()[1])')
endpoint=tcp/127.0.0.1:$port
domain=fleet-bench-$$

"$glintd" sim warehouse --seconds "$seconds" --seed 7 --out "$work/sim" > /dev/null
serve=()
[ -n "$map" ] && serve=(--serve-map "$map")
"$glintd" bridge --domain "$domain" --site bench --robot agv --listen "$endpoint" --insecure \
    "${serve[@]}" > "$work/bridge.out" 2> "$work/bridge.err" &
bridge=$!
pids+=("$bridge")
until grep -q ready "$work/bridge.err"; do
    kill -0 "$bridge" 2> /dev/null || { cat "$work/bridge.err" >&2; exit 1; }
    sleep 0.1
done
target/release/examples/fleet_latency "$domain" "$endpoint" bench agv > "$work/latency.out" &
pids+=("$!")
until grep -q subscribed "$work/latency.out"; do sleep 0.1; done

ticks() { awk '{print $14 + $15}' "/proc/$bridge/stat"; }
hz=$(getconf CLK_TCK)
t0=$(date +%s.%N); c0=$(ticks)
"$glintd" replay "$work/sim/scan.pcap" --domain "$domain" --pace realtime > /dev/null
t1=$(date +%s.%N); c1=$(ticks)
rss=$(awk '/VmRSS/ {print $2}' "/proc/$bridge/status")
hwm=$(awk '/VmHWM/ {print $2}' "/proc/$bridge/status")
wait "${pids[1]}"
latency=$(tail -n 1 "$work/latency.out")
cpu=$(awk -v c="$((c1 - c0))" -v hz="$hz" -v t0="$t0" -v t1="$t1" 'BEGIN { printf "%.2f", 100 * c / hz / (t1 - t0) }')
transfer=""
if [ -n "$map" ]; then
    name=$(basename "$map" .glintmap)
    line=$("$glintd" map fetch "$name" --site bench --connect "$endpoint" --insecure --out "$work/fetched.glintmap")
    echo "$line"
    transfer=" map_bytes=$(stat -c %s "$map") map_fetch_s=$(sed -n 's/.* in \([0-9.]*\) s .*/\1/p' <<< "$line")"
fi
echo "replay of ${seconds} s at the sensor's pace; bridge: cpu ${cpu} % of a core, rss ${rss} KiB (peak ${hwm} KiB)"
echo "seconds=$seconds $latency bridge_cpu_percent=$cpu bridge_rss_kib=$rss bridge_peak_rss_kib=$hwm$transfer"
