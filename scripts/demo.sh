#!/usr/bin/env bash
# The main job on the built-in simulated cell: bring the cell up, show every
# subunit's status, bring it down again.  Creates .venv on first use.
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/venv.sh
export PATH="$PWD/.venv/bin:$PATH"
droid-cell up
trap 'droid-cell down' EXIT
droid-cell status
for sub in arm1 gmf1 mvs tool; do
    droid-snoop "$sub" --count 1
done
