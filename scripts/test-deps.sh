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
# and its WebDriver server. A real PostgreSQL for the job store's contract
# tests (its programs only: the tests run initdb and pg_ctl themselves).
APT_INSTALL_FOR=test-deps bash "$(dirname "$0")/apt-install.sh" chromium chromium-driver postgresql
