#!/usr/bin/env bash
# Create (once) the project's virtual environment in .venv and install DROID into it
# with its test, plot, cluster and ros2 extras.  Used by scripts/demo.sh and scripts/test.sh.
#
# DROID builds one C extension at install, droid._kernel (the compiled 500 Hz servo PID and
# plant step, issue 28; setup.py): pip needs a C compiler and Python's headers.  When they are
# missing this script installs Debian's build-essential and python3-dev with apt-get (as root),
# else says what to install.
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-python3}
have_headers() {
    "$PY" -c 'import os, sysconfig, sys; sys.exit(not os.path.exists(os.path.join(sysconfig.get_paths()["include"], "Python.h")))'
}
if ! command -v cc >/dev/null 2>&1 || ! have_headers; then
    need="build-essential python3-dev"
    if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then
        echo "scripts/venv.sh: installing a C compiler and Python's headers ($need, apt-get) for droid._kernel" >&2
        { apt-get update -q && apt-get install -y -q $need; } >&2
    fi
    if ! command -v cc >/dev/null 2>&1 || ! have_headers; then
        echo "scripts/venv.sh: DROID's C extension needs a C compiler and Python's headers for $("$PY" -c 'import sys; print(sys.executable)'):" \
             "run 'apt-get install -y $need' (Debian/Ubuntu) and try again" >&2
        exit 1
    fi
fi
if [ ! -x .venv/bin/python ]; then
    "$PY" -m venv .venv
fi
stamp=.venv/.droid-installed
if [ ! -f "$stamp" ] || [ pyproject.toml -nt "$stamp" ] || [ setup.py -nt "$stamp" ] || [ droid/_kernel.c -nt "$stamp" ] || [ droid/guard/_guard.c -nt "$stamp" ]; then
    .venv/bin/python -m pip install --quiet --upgrade pip
    # ros2: droid-ros2's ROS 2 wheels (issue 42; ~230 MB, about a minute from an empty pip cache here), so
    # its tests run in CI.  Their ros_wheels_bootstrapper.pth re-executes every Python of the venv once at
    # start with the wheels' library path set (about 40 ms a start; docs/ros2.md)
    .venv/bin/python -m pip install --quiet -e ".[test,plots,cluster,ros2]"
    touch "$stamp"
fi
