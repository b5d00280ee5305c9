"""What the benchmarks that run a live cell share: a cell file copied under a fresh name, the
droid programs run on it, and the cell brought up with its arms homed.

Programs run two ways: :func:`droid_module` as ``python -m MODULE`` from this checkout (the
benches that sit beside ``bench/floor.py``), :func:`droid_program` as the installed console
script (``droid-cell``, ``droid-home``, ...) with ``--cell`` appended.
"""
from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def renamed_cell(text: str, name: str, run_dir) -> str:
    """A cell file's text under the cell name ``name``, its run directory ``run_dir`` (a line added
    after the name), so that a bench's cell shares no shm object or socket with another's."""
    return re.sub(r'(?m)^name = "[^"]*"', f'name = "{name}"\nrun_dir = "{run_dir}"', text, count=1)


def droid_module(mod: str, *args: str, timeout: float = 300) -> subprocess.CompletedProcess:
    """``python -m mod args`` from the checkout's root, its output captured as text."""
    return subprocess.run([sys.executable, "-m", mod, *args], capture_output=True, text=True, timeout=timeout,
                          cwd=ROOT)


def droid_program(cell: Path, *args: str, timeout: float = 300) -> subprocess.CompletedProcess:
    """The console script ``args[0]`` (beside this Python, else on PATH) with ``args[1:]`` and
    ``--cell cell``, its output captured as text."""
    exe = Path(sys.executable).parent / args[0]
    return subprocess.run([str(exe) if exe.exists() else args[0], *args[1:], "--cell", str(cell)],
                          capture_output=True, text=True, timeout=timeout)


def up_and_homed(cell: Path, arms=("arm1", "gmf1")) -> str | None:
    """``droid-cell up`` on ``cell``, then ``droid-home`` of each of ``arms``: None when all went
    well, else the one line that says what failed.  The caller brings the cell down either way."""
    up = droid_module("droid.brain.runtime.launcher", "up", "--cell", str(cell), timeout=180)
    if up.returncode != 0:
        return f"cell did not come up: {up.stderr.strip().splitlines()[-1:]}"
    for arm in arms:
        out = droid_module("droid.tasks.home", arm, "--cell", str(cell), timeout=200)
        if out.returncode != 0:
            return f"droid-home {arm} failed: {out.stderr.strip()}"
    return None
