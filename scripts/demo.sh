#!/usr/bin/env bash
# The main job on the built-in simulated cell: bring the cell up, home the Reis,
# move it to the seam-tracking start position, show every subunit's status,
# bring the cell down again.  Creates .venv on first use.
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/venv.sh
export PATH="$PWD/.venv/bin:$PATH"
droid-cell up
trap 'droid-cell down' EXIT
droid-cell status
droid-home arm1
droid-move arm1 joint 0 0 0 0 0 0 2
droid-move arm1 cart 300 100 1340 0 180 0 3   # sensor over the seam (docs/mvs.md)
for sub in arm1 gmf1 mvs tool; do
    droid-snoop "$sub" --count 1
done
