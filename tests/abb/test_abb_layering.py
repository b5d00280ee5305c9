"""docs/design.md §7 for the ABB package: the subunit side never imports the world; the twin imports only
subunits, brain, kinematics and the world's own Device base."""
from __future__ import annotations

from tests.layering import DROID, droid_imports, within


def test_subunit_side_imports_no_world():
    for path in (DROID / "subunits" / "abb").rglob("*.py"):
        for n in droid_imports(path):
            assert within(n, ("droid.brain", "droid.kinematics", "droid.cli", "droid.numbers",
                              "droid.subunits", "droid.arm")), (path, n)


TWIN = ("droid.brain", "droid.kinematics", "droid.cli", "droid.numbers", "droid.subunits", "droid.sim.device",
        "droid.arm", "droid.sim.truth")  # droid.arm: the neutral arm (its twin's dynamics)
#: the lockstep assembly (droid.sim.abb.lockstep) also steps the twin on the lockstep scheduler, with
#: the Brain side every lockstep arm shares, the world's truth record's format and the registry's
#: lockstep slot's protocol (droid.sim.lockstep_build)
LOCKSTEP = TWIN + ("droid.sim.abb", "droid.sim.lockstep", "droid.sim.arm_chain", "droid.sim.lockstep_build")


def test_twin_imports():
    for path in (DROID / "sim" / "abb").rglob("*.py"):
        allowed = LOCKSTEP if path.name == "lockstep.py" else TWIN
        for n in droid_imports(path):
            assert within(n, allowed), (path, n)
