#!/usr/bin/env bash
# The main job on the built-in simulated cell: bring the cell up, home both arms,
# run one dynamic seam-tracking trial end to end (thesis chapters 5-6), print its
# summary and the path of its figure, bring the cell down again.
# Creates .venv on first use.  Output: out/demo/ (CSV log and PNG figure).
# scripts/demo.sh --force: start the cell even over this host's real-time budget (droid-cell up
# --force; e.g. pinned to one CPU with taskset -c 0).
set -euo pipefail
up_flags=()
case "${1:-}" in
    "") ;;
    --force) up_flags=(--force) ;;
    *) echo "usage: scripts/demo.sh [--force]" >&2; exit 2 ;;
esac
cd "$(dirname "$0")/.."
scripts/venv.sh
export PATH="$PWD/.venv/bin:$PATH"
out=out/demo
mkdir -p "$out"
droid-cell up "${up_flags[@]}"
trap 'droid-cell down' EXIT
droid-cell status
droid-home arm1     # the Reis: its 500 Hz servo searches the limit switches (thesis §4.1.5.3)
droid-home gmf1     # the Fanuc: its KAREL controller goes home, the encoder cards are zeroed
# Start position (i) of the layout (cells/seamtrack_layout.toml): the Fanuc holds the
# step-input workpiece, the Reis puts its lead sensor on the seam start; then track
# 400 mm of the seam (over the 5 degree step at 100 mm) at 16 mm/s in plus mode (the
# seam-map tracker, docs/seamtrack.md; `--mode thesis` runs the thesis's tracker).
droid-seamtrack 16 --mode plus --start i --length 400 --log "$out/seamtrack.csv" --figure "$out/seamtrack.png"
for sub in arm1 gmf1 mvs tool; do
    droid-snoop "$sub" --count 1
done
