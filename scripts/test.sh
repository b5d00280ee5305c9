#!/usr/bin/env bash
# Run the test suite in the project's virtual environment (created on first use).
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/venv.sh
# the real-browser test of droid-web needs chromium; if it cannot be installed that test fails (it never skips)
scripts/browser.sh || echo "scripts/test.sh: chromium unavailable: tests/observe/test_web_browser.py will fail" >&2
exec .venv/bin/python -m pytest -q "$@"
