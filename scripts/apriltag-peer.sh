#!/usr/bin/env bash
# Prints the python of a virtualenv holding the AprilTag 3 peer
# (pupil-apriltags from PyPI) for the throughput bench, creating it once.
set -euo pipefail
venv="${GCP_TAGGER_PEER_VENV:-$HOME/.cache/gcp-tagger/peer-venv}"
if ! "$venv/bin/python" -c "import pupil_apriltags, tifffile, PIL, numpy" >/dev/null 2>&1; then
  echo "apriltag-peer: installing pupil-apriltags into $venv" >&2
  python3 -m venv "$venv"
  "$venv/bin/pip" install -q --disable-pip-version-check \
    'pupil-apriltags==1.0.4.post11' numpy pillow tifffile >&2
fi
echo "$venv/bin/python"
