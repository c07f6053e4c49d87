#!/usr/bin/env bash
# Soak: hours of sensor data through the whole pipeline without a restart, in SLAM mode and in
# localisation mode, at the stages' own pace. `glintd soak` runs a simulated VLP-16 in process
# (no capture file) and samples resident memory, per-sweep CPU time, per-sweep compute and
# latency once a minute into a CSV; this script makes the site map the localisation soak runs
# in, runs both soaks one after the other, and writes docs/soak.md with its plot docs/soak.png.
#
#   bash scripts/soak.sh [SWEEPS] [OUT_DIR]        # defaults: 200000 target/soak
#   SOAK_SCENARIO=yard SOAK_SEED=4 bash scripts/soak.sh 20000
#
# 200,000 sweeps are 5.6 h of sensor time; on 2 cores each soak takes about an hour.
# The plot needs matplotlib: it is installed into a virtual environment under OUT_DIR if the
# system's Python lacks it. Not run by CI.
set -euo pipefail
cd "$(dirname "$0")/.."
sweeps=${1:-200000}
out=${2:-target/soak}
scenario=${SOAK_SCENARIO:-warehouse}
seed=${SOAK_SEED:-1}
every=${SOAK_EVERY:-60}
plot=${SOAK_PLOT:-docs/soak.png}
report=${SOAK_REPORT:-docs/soak.md}
cargo build --release -p glintd --quiet
mkdir -p "$out"
# Its own copy: a rebuild while the soak runs must not change the second run's binary.
cp target/release/glintd "$out/glintd"
glintd=$out/glintd
# The daemon's environment as the systemd unit sets it (the malloc thresholds), so the soak
# measures the memory behaviour a robot gets.
read -r -a unit_env <<< "$(sed -n 's/^Environment=//p' systemd/glintd.service | tr '\n' ' ')"

echo "== the site map: two laps of the $scenario (seed $seed), mapped"
"$glintd" sim "$scenario" --seed "$seed" --seconds 80 --out "$out/site" > "$out/site.log"
"$glintd" replay "$out/site/scan.pcap" --no-publish --save-map "$out/site.glintmap" >> "$out/site.log"
rm -f "$out/site/scan.pcap"

for mode in slam localisation; do
    echo "== $mode: $sweeps sweeps, a sample every $every s -> $out/$mode.csv"
    extra=()
    if [ "$mode" = localisation ]; then
        extra=(--localise "$out/site.glintmap")
    fi
    status=0
    env "${unit_env[@]}" "$glintd" soak --scenario "$scenario" --seed "$seed" --sweeps "$sweeps" --every "$every" \
        --domain "soak-$mode" --csv "$out/$mode.csv" "${extra[@]}" > "$out/$mode.log" 2>&1 \
        || status=$?
    tail -n 3 "$out/$mode.log"
    if [ "$status" -ne 0 ] || grep -q "panicked" "$out/$mode.log"; then
        echo "soak: the $mode run failed (exit $status); see $out/$mode.log" >&2
        exit 1
    fi
done

python=python3
if ! "$python" -c 'import matplotlib' 2> /dev/null; then
    [ -x "$out/venv/bin/python" ] || { python3 -m venv "$out/venv" && "$out/venv/bin/pip" install --quiet matplotlib; }
    python=$out/venv/bin/python
fi
"$python" scripts/soak_plot.py --slam "$out/slam.csv" --localisation "$out/localisation.csv" \
    --slam-log "$out/slam.log" --localisation-log "$out/localisation.log" \
    --plot "$plot" --report "$report" --command "bash scripts/soak.sh $sweeps"
