# Sourced by the other scripts: where cargo builds. Outside the clone, so CI's
# fresh clones reuse one build cache; works when the folder is empty.
export CARGO_TARGET_DIR="${CARGO_TARGET_DIR:-$HOME/.cache/gcp-tagger/target}"
if [ -f "$HOME/.cargo/env" ]; then . "$HOME/.cargo/env"; fi
