"""Lockstep fixtures for the Reis tests: a simulated arm + servo + watchdog on virtual time."""
from __future__ import annotations

import pytest

from droid.sim.reis.plant import ReisPlantParams
from droid.sim.reis.lockstep import make_reis_cell, run_homing

# power-up pose a little off the home switches (both sides), so homing takes ~3 s simulated
NEAR_SWITCH_OFFSET_DEG = (0.4, -0.3, 0.3, -0.4, 0.3, -0.3)


@pytest.fixture
def homed_cell():
    # rigid drives: the servo's count logic is exact there (the compliant arm: test_plant_dynamics.py)
    ls = make_reis_cell(seed=21, near_switch_offset_deg=NEAR_SWITCH_OFFSET_DEG,
                        plant_params=ReisPlantParams(compliance=False))
    ls.run(0.05)
    run_homing(ls)
    assert ls.servo.homed
    yield ls
    ls.close()
