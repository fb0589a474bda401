#!/usr/bin/env bash
# Measures fetching frames from a local S3 server: a flight of large
# uncompressed GeoTIFFs (about 100 MB each) in moto_server on 127.0.0.1,
# submitted as one prefix; prints each fetch's time and rate and the
# server's peak RSS against an idle server's.
#   bash scripts/bench-s3.sh [frames=3] [side=5800] [fetch-only]
# fetch-only uploads random bytes of the same size instead: every job then
# fails as not an image after its download, so the peak RSS is the
# fetcher's alone.
set -euo pipefail
cd "$(dirname "$0")/.."
frames=${1:-3}
side=${2:-5800}
bash scripts/test-deps.sh
. scripts/env.sh
cargo build --release --locked -q
bin="$CARGO_TARGET_DIR/release/gcp-tagger"
work=$(mktemp -d)
cleanup() { kill "${server:-}" "${moto:-}" 2>/dev/null || true; wait 2>/dev/null || true; rm -rf "$work"; }
trap cleanup EXIT

port=$(python3 -c 'import socket; s=socket.socket(); s.bind(("127.0.0.1",0)); print(s.getsockname()[1])')
python3 -m moto.server -H 127.0.0.1 -p "$port" >/dev/null 2>&1 &
moto=$!
until python3 -c "import socket; socket.create_connection(('127.0.0.1',$port),1)" 2>/dev/null; do sleep 0.2; done
endpoint="http://127.0.0.1:$port"

gdal_create -q -of GTiff -outsize "$side" "$side" -bands 3 -ot Byte -burn 90 \
  -a_srs EPSG:32611 -a_ullr 500000 4100000 $((500000 + side / 20)) $((4100000 - side / 20)) \
  "$work/frame.tif"
bytes=$(stat -c %s "$work/frame.tif")
if [ "${3:-}" = fetch-only ]; then
  head -c "$bytes" /dev/urandom >"$work/frame.tif"
fi
ops="[{\"op\":\"bucket\",\"bucket\":\"bench\"}"
for i in $(seq 1 "$frames"); do
  ops+=",{\"op\":\"put\",\"bucket\":\"bench\",\"key\":\"flight/frame_$i.tif\",\"file\":\"$work/frame.tif\"}"
done
echo "$ops]" | python3 tests/fixtures/s3_fixture.py "$endpoint" k s >/dev/null

AWS_ACCESS_KEY_ID=k AWS_SECRET_ACCESS_KEY=s AWS_REGION=us-east-1 \
  "$bin" serve --listen 127.0.0.1:0 --data-dir "$work/data" --s3-endpoint "$endpoint" \
  --workers 1 --log-json >"$work/out" 2>"$work/log" &
server=$!
until grep -q listening "$work/out" 2>/dev/null; do sleep 0.1; done
base=$(sed -n 's/.*listening on //p' "$work/out")
idle=$(awk '/VmHWM/ {print $2}' /proc/$server/status)
start=$(date +%s.%N)
flight=$(curl -sf -H 'Content-Type: application/json' -d '{"sources":["s3://bench/flight/"]}' \
  "$base/v1/flights" | python3 -c 'import json,sys; print(json.load(sys.stdin)["flight"]["id"])')
until curl -sf "$base/v1/flights/$flight?wait=30" | grep -q '"state":"finished"'; do :; done
end=$(date +%s.%N)
peak=$(awk '/VmHWM/ {print $2}' /proc/$server/status)
echo "object: $((bytes / 1000000)) MB (${side}x${side}x3 GeoTIFF), $frames in one prefix, moto_server on 127.0.0.1, 1 worker"
python3 - "$work/log" "$bytes" <<'PY'
import json, sys
for line in open(sys.argv[1]):
    try:
        rec = json.loads(line)
    except ValueError:
        continue
    fields = rec.get("fields", {})
    if fields.get("message") == "frame fetched":
        secs = float(fields["secs"])
        print(f"fetch: {secs:.2f} s, {int(sys.argv[2]) / 1e6 / secs:.0f} MB/s")
PY
python3 -c "print(f'flight (fetch + detection): {$end - $start:.1f} s')"
echo "server peak RSS: idle $((idle / 1024)) MiB, after the flight $((peak / 1024)) MiB"
curl -sf "$base/v1/flights/$flight" | python3 -c 'import json,sys; print("jobs:", json.load(sys.stdin)["jobs"])'
