#!/usr/bin/env bash
# The test command: installs what is missing, builds, runs every test.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
bash scripts/test-deps.sh
. scripts/env.sh
if cargo fmt --version >/dev/null 2>&1; then
  cargo fmt --all -- --check
else
  echo "test: rustfmt not installed; skipping the format check (rustup component add rustfmt)" >&2
fi
if cargo clippy --version >/dev/null 2>&1; then
  cargo clippy --workspace --all-targets --locked -- -D warnings
else
  echo "test: clippy not installed; skipping the lint (rustup component add clippy)" >&2
fi
suite_start=$SECONDS
cargo test --workspace --all-targets --locked "$@"
suite_seconds=$((SECONDS - suite_start))
bash scripts/schemathesis.sh
bash scripts/lint-deploy.sh
echo "test: everything passed in $SECONDS s (cargo test: $suite_seconds s, builds included)" >&2
