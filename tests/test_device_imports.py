"""No device package imports another device package (issue 43: "no arm package imports another").

A *device package* is a folder under ``droid/subunits/`` (the programs, stations and drivers of one
device: ``reis``, ``gmf1``, ``abb``, ``mvs``, ``joystick``, ``ft``) or under ``droid/sim/`` (its twin and
lockstep builder, at the same name); ``droid/subunits/reis/`` and ``droid/sim/reis/`` are one device.
What several devices share lives outside every device package: the neutral arm (``droid.arm``: the
planner, the tick pacer, the rigid body, the ``Arm`` protocol), the Brain, the kinematics, the
generic agent (``droid/subunits/agent.py``) and the simulator's shared modules (``droid/sim/*.py``).
Every import counts, at a file's top or inside a function (docs/design.md §7), as in
tests/test_import_circles.py.
"""
from __future__ import annotations

from pathlib import Path

from tests.layering import DROID, droid_imports

ROOTS = ("subunits", "sim")


def device_of_module(name: str, droid: Path = DROID) -> str | None:
    """The device package of module ``name`` (``droid.subunits.reis.servo`` -> ``reis``), or None."""
    parts = name.split(".")
    if len(parts) < 3 or parts[0] != "droid" or parts[1] not in ROOTS:
        return None
    return parts[2] if (droid / parts[1] / parts[2]).is_dir() else None


def device_of_file(path: Path, droid: Path = DROID) -> str | None:
    rel = path.relative_to(droid).parts
    return rel[1] if len(rel) > 2 and rel[0] in ROOTS else None


def crossings(droid: Path = DROID) -> list[str]:
    """``file: imported module (device -> device)`` for every import of one device package by another."""
    found = []
    for root in ROOTS:
        for path in sorted((droid / root).rglob("*.py")):
            mine = device_of_file(path, droid)
            if mine is None:
                continue
            for name in droid_imports(path):
                theirs = device_of_module(name, droid)
                if theirs is not None and theirs != mine:
                    found.append(f"{path.relative_to(droid.parent)}: {name} ({mine} -> {theirs})")
    return found


def test_the_finder_sees_a_late_import_of_another_device(tmp_path):
    droid = tmp_path / "droid"
    for d in ("subunits/abb", "subunits/reis", "sim/gmf1", "sim/abb"):
        (droid / d).mkdir(parents=True)
    (droid / "subunits" / "agent.py").write_text("from droid.subunits.reis import servo\n")  # not a device
    (droid / "sim" / "abb" / "twin.py").write_text(
        "from droid.subunits.abb import egm_core\nfrom droid.arm.rigid_body import RigidBody\n"
        "def f():\n    from droid.sim.gmf1.karel import KarelDevice\n")
    (droid / "subunits" / "abb" / "prog.py").write_text("import droid.subunits.reis.servo_agent\n")
    assert crossings(droid) == [
        "droid/subunits/abb/prog.py: droid.subunits.reis.servo_agent (abb -> reis)",
        "droid/sim/abb/twin.py: droid.sim.gmf1.karel (abb -> gmf1)"]


def test_no_device_package_imports_another():
    found = crossings()
    assert not found, "device packages importing another device package:\n" + "\n".join(found)
