#!/usr/bin/env bash
# Runs the printed-target detectors on the clutter-only sets measured in the
# README ("Beyond the test's frames") and prints the detections per set and in all:
# every one is a false positive. Two streams (about 45 min on 2 cores).
#
#     bash tools/clutter-sets.sh            # all 36 sets, 558 frames
#     bash tools/clutter-sets.sh 900:16     # any SEED:FRAMES sets
#     ONLY=circle bash tools/clutter-sets.sh  # one mode alone (about half the time)
set -euo pipefail
cd "$(dirname "$0")/.."
. scripts/env.sh
cargo build --release --locked -p gcp-tools --bin printed_misses
bin="$CARGO_TARGET_DIR/release/printed_misses"
sets=("$@")
if [ ${#sets[@]} -eq 0 ]; then
  sets=(0:10 100:16 300:16 400:16 30:8 40:20 200:16 500:8 600:16 700:16 800:16
    900:16 1000:16 1100:16 1200:16 1300:16 1400:16 1500:16 1600:16 1700:16
    1800:16 1900:16 2000:16 2100:16 2200:16 2300:16 2400:16 2500:16 2600:16
    2700:16 2800:16 2900:16 3000:16 3100:16 3200:16 3300:16)
fi
out=$(mktemp -d)
trap 'rm -rf "$out"' EXIT
run() {
  local seed=${1%%:*} frames=${1##*:}
  "$bin" clutter "$seed" "$frames" 2>&1 | grep -a " FP " > "$out/$seed" || true
  echo "clutter $seed $frames (scenes $((700 + seed))-$((700 + seed + frames - 1))): $(wc -l < "$out/$seed")"
}
# Two streams: the sets alternate between them.
for stream in 0 1; do
  (
    for i in "${!sets[@]}"; do
      if [ $((i % 2)) -eq "$stream" ]; then run "${sets[$i]}"; fi
    done
  ) &
done
wait
frames=0
for s in "${sets[@]}"; do frames=$((frames + ${s##*:})); done
echo "total: $(cat "$out"/* | wc -l) detections on $frames frames"
cat "$out"/*
