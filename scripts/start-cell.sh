#!/usr/bin/env bash
# Bring the default simulated cell up by hand, program by program, as a UNIX
# user would.  `droid-cell up` does the same in parallel with a readiness
# handshake; this script shows the pieces.  Stop it all with `droid-cell down`.
#
#   scripts/start-cell.sh [CELL_FILE]     (default: $DROID_CELL or the built-in cell)
#   droid-cell status
#   droid-snoop arm1 --count 3
#   droid-cell down
set -euo pipefail
if [ $# -gt 0 ]; then export DROID_CELL=$1; fi
LOGS=${LOGS:-/tmp/droid-logs}
mkdir -p "$LOGS"

bg() {  # bg LOGNAME PROGRAM ARGS...: start one program in the background
    local log=$1; shift
    "$@" >"$LOGS/$log.log" 2>&1 &
    echo "started $* (pid $!)"
}

# 1. The Brain's initialization software builds the databases (thesis §3.2) ...
droid-cell init
# 2. ... the name space, where subunits and the heartbeat register ...
bg names droid-names
sleep 0.5
# 3. ... the simulated hardware (on a real cell: power the robots and sensors on) ...
bg sim droid-sim
# 4. ... the Reis motion controller (thesis §4.1.4: watchdog, servo, servo agent) ...
bg watchdog-arm1 droid-watchdog arm1
bg servo-arm1 droid-servo arm1
bg servo-agent-arm1 droid-servo-agent arm1
# 5. ... each subunit identifies itself in the name space through its agent ...
bg agent-arm1 droid-reis-agent arm1
bg agent-gmf1 droid-gmf1-agent gmf1
bg gmf1-serial-gmf1 droid-gmf1-serial gmf1     # the KAREL controller's serial line (§4.2.4)
bg gmf1-encoder-gmf1 droid-gmf1-encoder gmf1   # the encoder cards, 120 Hz (§4.2.5)
# the MVS sensor PC runs the sensor program; its lines reach the Brain by a serial cable
bg mvs-mvs droid-mvs mvs
bg planner-arm1 droid-planner arm1
# the Brain's joystick (thesis §3.4): its device reader and its agent
bg joystick-joy droid-joystick joy
bg agent-joy droid-agent joy
# the force/torque sensor on the Reis wrist (thesis §7.3): its RDT reader and its agent
bg ft-ft droid-ft ft
bg agent-ft droid-agent ft
# 6. ... one remote client per subunit on the Brain ...
for sub in arm1 gmf1 mvs tool joy ft; do bg "remote-$sub" droid-remote "$sub"; done
# the collision guard, where the cell runs one ([guard] run = true, as the built-in cell: docs/guard.md §9)
py="$(dirname "$(command -v droid-cell)")/python"
if "$py" -c 'import sys; from droid.brain.cell.cellfile import load_cell; from droid.guard.gate import guard_runs
sys.exit(0 if guard_runs(load_cell()) else 1)'; then
    bg guard droid-guard
fi
# 7. ... and the heartbeat that paces them all (60 Hz).
bg heartbeat droid-heartbeat
# wait (bounded) until every program says it is live, then show them
for _ in $(seq 60); do
    droid-cell status >/dev/null 2>&1 && break
    sleep 0.5
done
droid-cell status
