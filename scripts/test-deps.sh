#!/usr/bin/env bash
# What the tests need besides the native libraries: a local S3 server
# (moto_server) and a real S3 client (boto3) for the S3 tests' fixtures, and
# a headless browser for the review page's test.
set -euo pipefail
if ! python3 -c "import moto.server, boto3, flask" >/dev/null 2>&1; then
  echo "test-deps: installing moto[server] and boto3 from PyPI" >&2
  python3 -m pip install -q --disable-pip-version-check 'moto[server]==5.2.1' 'boto3>=1.35'
fi

# A real browser for the review page's end-to-end test: Debian's chromium
# and its WebDriver server.
browser=()
for p in chromium chromium-driver; do
  if ! dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed"; then
    browser+=("$p")
  fi
done
if [ "${#browser[@]}" -gt 0 ]; then
  if [ "$(id -u)" -eq 0 ]; then SUDO=""; else SUDO="sudo"; fi
  echo "test-deps: installing ${browser[*]}" >&2
  export DEBIAN_FRONTEND=noninteractive
  $SUDO apt-get update -qq
  $SUDO apt-get install -y -qq --no-install-recommends "${browser[@]}" >/dev/null
fi
