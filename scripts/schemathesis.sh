#!/usr/bin/env bash
# Fuzzes the running service from the committed OpenAPI document with
# schemathesis (PyPI): every operation, generated and mutated requests,
# stateful sequences. Fails on any 5xx, any response that violates the
# spec (schema, status code, content type). Part of the test command.
set -euo pipefail
cd "$(dirname "$0")/.."
. scripts/env.sh
if ! command -v schemathesis >/dev/null 2>&1; then
  echo "schemathesis: installing from PyPI" >&2
  python3 -m pip install -q --disable-pip-version-check 'schemathesis==4.32.5'
  if command -v pyenv >/dev/null 2>&1; then pyenv rehash; fi
  PATH="$PATH:$(python3 -m site --user-base)/bin"
fi
cargo build --locked -q
work=$(mktemp -d)
out="$work/stdout"
"$CARGO_TARGET_DIR/debug/gcp-tagger" serve --listen 127.0.0.1:0 --data-dir "$work/data" \
  --rate-limit-per-minute 0 >"$out" 2>"$work/log" &
server=$!
cleanup() { kill "$server" 2>/dev/null || true; wait "$server" 2>/dev/null || true; rm -rf "$work"; }
trap cleanup EXIT
for _ in $(seq 100); do grep -q listening "$out" 2>/dev/null && break; sleep 0.1; done
url=$(sed -n 's/.*listening on //p' "$out")
schemathesis run openapi/openapi.json --url "$url" \
  --checks not_a_server_error,response_schema_conformance,status_code_conformance,content_type_conformance \
  --max-examples 30 --generation-deterministic
