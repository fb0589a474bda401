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

APT_INSTALL_FOR=setup bash "$(dirname "$0")/apt-install.sh" "${APT_PACKAGES[@]}"

if ! command -v cargo >/dev/null 2>&1; then
  echo "setup: cargo not found; install Rust from rustup (https://rustup.rs) first" >&2
  exit 1
fi
