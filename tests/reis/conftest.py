"""Lockstep fixtures for the Reis tests: a simulated arm + servo + watchdog on virtual time."""
from __future__ import annotations

import pytest

from droid.sim.reis.lockstep import homed_rigid_cell


@pytest.fixture
def homed_cell():
    ls = homed_rigid_cell()
    yield ls
    ls.close()
