#!/usr/bin/env bash
# Installs what gcp-tagger needs on Debian/Ubuntu, skipping what is already there.
# Idempotent; runs as root directly, through sudo otherwise.
set -euo pipefail

# Native libraries (OpenCV 4.6 + contrib for aruco, libapriltag 3 for AprilTags, GDAL, PROJ), libclang for the
# opencv binding generator, and the command-line tools the tests compare against
# (gdaltransform, cs2cs).
APT_PACKAGES=(
  libopencv-dev libopencv-contrib-dev libgdal-dev libproj-dev libclang-dev clang
  libapriltag-dev pkg-config gdal-bin proj-bin
)

missing=()
for p in "${APT_PACKAGES[@]}"; do
  if ! dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed"; then
    missing+=("$p")
  fi
done

if [ "${#missing[@]}" -gt 0 ]; then
  if [ "$(id -u)" -eq 0 ]; then SUDO=""; else SUDO="sudo"; fi
  echo "setup: installing ${missing[*]}" >&2
  export DEBIAN_FRONTEND=noninteractive
  $SUDO apt-get update -qq
  $SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
fi

if ! command -v cargo >/dev/null 2>&1; then
  echo "setup: cargo not found; install Rust from rustup (https://rustup.rs) first" >&2
  exit 1
fi
