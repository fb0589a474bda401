#!/usr/bin/env bash
# The main command: installs what is missing, builds, and starts the service
# on its embedded defaults (http://127.0.0.1:8080, data in ./gcp-tagger-data,
# memory limit half of the machine's). Extra arguments go to `serve`, e.g.
#   bash scripts/run.sh --listen 0.0.0.0:8080 --max-ram-gb 4
# Stop it with Ctrl-C (running jobs get the grace period, the rest stay queued).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
. scripts/env.sh
cargo build --release --locked
exec "$CARGO_TARGET_DIR/release/gcp-tagger" serve "$@"
