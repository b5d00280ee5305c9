#!/usr/bin/env bash
# Run the README's test command from a fresh clone with N busy processes in the background
# (issue 16 item 4: the suite must pass every time on a loaded host).
#
#   bench/suite_under_load.sh [--busy N] [--runs K] [--out DIR] [-- PYTEST-ARGS...]
#
# Each run clones the current repository's HEAD into DIR/run-I (a fresh clone: a new .venv,
# nothing left over), starts N CPU-bound loops at normal priority, runs `CI=true bash .ci/run`
# (or scripts/test.sh with PYTEST-ARGS when given, e.g. --durations=40), stops the loops and
# prints one line per run: start time (UTC), commit, busy processes, pytest's closing line,
# exit code and wall time.  The loops are killed on any exit, Ctrl-C included.
set -euo pipefail
busy=2
runs=1
out=/tmp/droid-suite
pytest_args=()
while [ $# -gt 0 ]; do
    case "$1" in
        --busy) busy=$2; shift 2 ;;
        --runs) runs=$2; shift 2 ;;
        --out) out=$2; shift 2 ;;
        --) shift; pytest_args=("$@"); break ;;
        -h|--help) sed -n '2,12p' "$0" | sed 's/^# \{0,1\}//'; exit 0 ;;
        *) echo "suite_under_load.sh: unknown argument '$1' (see --help)" >&2; exit 2 ;;
    esac
done
case "$busy$runs" in *[!0-9]*) echo "suite_under_load.sh: --busy and --runs take whole numbers" >&2; exit 2 ;; esac
repo=$(git -C "$(dirname "$0")/.." rev-parse --show-toplevel)
commit=$(git -C "$repo" rev-parse --short HEAD)
mkdir -p "$out"
pids=()
stop_busy() { for p in "${pids[@]}"; do kill "$p" 2>/dev/null || true; done; pids=(); }
trap stop_busy EXIT INT TERM
for i in $(seq 1 "$runs"); do
    dir="$out/run-$commit-$i"
    rm -rf "$dir"
    git clone -q "$repo" "$dir"
    for _ in $(seq 1 "$busy"); do
        ( trap - INT TERM; while :; do :; done ) &
        pids+=($!)
    done
    start=$(date -u +%H:%M:%S)
    t0=$(date +%s)
    set +e
    if [ ${#pytest_args[@]} -gt 0 ]; then
        (cd "$dir" && CI=true bash scripts/test.sh "${pytest_args[@]}") > "$dir.log" 2>&1
    else
        (cd "$dir" && CI=true bash .ci/run) > "$dir.log" 2>&1
    fi
    rc=$?
    set -e
    stop_busy
    t1=$(date +%s)
    summary=$(grep -E '^(=+ )?[0-9]+ (passed|failed)|^=+ .*(passed|failed).* =+$' "$dir.log" | tr '\n' ' ')
    printf '%s UTC  commit %s  busy %s  rc %s  %dm%02ds  %s  (log %s)\n' \
        "$start" "$commit" "$busy" "$rc" $(((t1 - t0) / 60)) $(((t1 - t0) % 60)) "$summary" "$dir.log"
done
