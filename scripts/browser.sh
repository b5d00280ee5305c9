#!/usr/bin/env bash
# Make sure Debian's chromium is installed for the real-browser test of droid-web
# (tests/observe/test_web_browser.py drives it headless through playwright).
# Installs it with apt-get when missing (needs root); fails with a clear message otherwise.
set -euo pipefail
if command -v chromium >/dev/null 2>&1; then
    exit 0
fi
if [ "$(id -u)" != "0" ]; then
    echo "scripts/browser.sh: chromium is not installed and this is not root: run 'apt-get install -y chromium'" >&2
    exit 1
fi
echo "scripts/browser.sh: installing chromium (apt-get) for the browser test" >&2
export DEBIAN_FRONTEND=noninteractive
if ! { apt-get update -q && apt-get install -y -q chromium; } >&2; then
    echo "scripts/browser.sh: could not install chromium with apt-get: the browser test cannot run" >&2
    exit 1
fi
command -v chromium >/dev/null 2>&1 || { echo "scripts/browser.sh: chromium still missing after apt-get" >&2; exit 1; }
