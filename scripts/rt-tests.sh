#!/usr/bin/env bash
# Install Debian's rt-tests (cyclictest) when missing: the benchmarks measure the machine's
# latency floor with it in the same run as their own figures (docs/benchmarks.md).  Needs root.
set -euo pipefail
command -v cyclictest >/dev/null 2>&1 && exit 0
if [ "$(id -u)" != "0" ]; then
    echo "scripts/rt-tests.sh: cyclictest is missing and this is not root: run 'apt-get install -y rt-tests'" >&2
    exit 1
fi
export DEBIAN_FRONTEND=noninteractive
{ apt-get update -q && apt-get install -y -q rt-tests; } >&2
command -v cyclictest >/dev/null 2>&1
