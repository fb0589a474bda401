#!/usr/bin/env bash
# The command-line demo: installs what is missing, builds, renders sample frames
# with known targets and detects them. Extra arguments go to `detect`.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
. scripts/env.sh
cargo build --release --locked
bin="$CARGO_TARGET_DIR/release/gcp-tagger"
out="${GCP_TAGGER_DEMO_DIR:-$PWD/demo}"
if [ ! -f "$out/frames/truth.csv" ]; then
  "$bin" sample --out "$out/frames" --frames 4 --width 4000 --height 3000 --markers 6 --kind gtiff
fi
"$bin" detect "$out/frames" --marker-type apriltag --crs EPSG:4326 --output "$out/results.csv" "$@"
"$bin" detect "$out/frames" --marker-type apriltag --crs EPSG:4326 --output "$out/results.geojson" --quiet "$@"
echo "results: $out/results.csv and $out/results.geojson (truth: $out/frames/truth.csv)"
head -n 5 "$out/results.csv"
