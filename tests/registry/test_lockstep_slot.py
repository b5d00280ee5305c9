"""An external device package in lockstep through its registration only (issue 25 item 2).

A package outside the repository, ``lablock``, is written into tmp_path with a dist-info
``entry_points.txt`` (as ``labsensor`` in test_registry.py): its ``device.py`` declares its class,
its program and ``lockstep="lablock.lockstep:build"``; its ``lockstep.py`` is the only lockstep
code it has -- a builder on the protocol of droid.sim.lockstep_build.  A cell with two of its
subunits beside a bundled Reis arm builds and runs; its Status carries what its station wrote,
through droid-agent and droid-remote.  A package that registers no builder is refused in one
line (``labsensor``, whose slot is empty).
"""
from __future__ import annotations

import pytest

from droid.brain.cell import registry as R
from droid.cli import BadInput
from droid.sim.lockstep_cell import build_lockstep_cell
from tests.registry.test_registry import LAB_SUBUNIT, cell_text, lab, registered  # noqa: F401 (a fixture)

LABLOCK_DEVICE = '''
"""lablock: a lab's counter, registered through droid.devices, with its own lockstep builder."""
from droid.brain.cell.classes import SubunitClass
from droid.brain.db.layouts import HEADER_FIELDS, Layout, record_dtype
from droid.brain.cell.registry import DevicePackage, Program

FIELDS = (("count", "<u8"), ("tick", "<u8"), ("updated_ns", "<i8"), ("stale", "<u4"), ("fault", "<u4"))
LOCK_STATUS = Layout("lablock_status", 111, 1, record_dtype(HEADER_FIELDS + [(f, t, None) for f, t in FIELDS], 64),
                     "droid_lablock_status")  # count: the station's cycles
LABLOCK = SubunitClass(name="lablock", description="a lab's counter", brain={"status": LOCK_STATUS},
                       local={"ctrl_status": LOCK_STATUS}, copy_fields=("count", "fault"), snoop_fields=("count",))

PACKAGE = DevicePackage(
    name="lablock",
    classes=(LABLOCK,),
    programs=(Program("droid-lablock", "lablock.prog", rate_hz=40.0),),
    lockstep="lablock.lockstep:build",
)
'''

LABLOCK_PROG = '''
def main(argv=None):
    return 0
'''

LABLOCK_LOCKSTEP = '''
from droid.sim.lockstep_build import AGENT, AgentLink, LockstepSubunit, brain_databases, builds, local_databases


@builds("droid-lablock", AGENT)
def build(ctx, sub):
    brain, local = brain_databases(sub), local_databases(sub)
    status = local["ctrl_status"]

    def cycle(t_ns):
        status.update(count=int(status.read()["count"]) + 1, updated_ns=t_ns)

    ctx.sched.every(ctx.rate_hz("droid-lablock"), cycle, f"{sub.name}.lablock")
    link = AgentLink(ctx, sub, brain, local)
    return LockstepSubunit(sub.name, sub.cls, brain["status"], None,
                           {"droid-lablock": [f"{sub.name}.lablock"], AGENT: [link.task]})
'''

LOCK_SUBUNITS = "".join(f"""
[subunits.{n}]
class = "lablock"
programs = ["droid-lablock", "droid-agent"]
""" for n in ("c1", "c2")) + """
[subunits.arm1]
class = "arm6r"
robot = "reis_v15"
programs = ["droid-watchdog", "droid-servo", "droid-servo-agent", "droid-reis-agent", "droid-planner"]
"""


@pytest.fixture
def lablock(tmp_path, monkeypatch):
    files = {"device.py": LABLOCK_DEVICE, "prog.py": LABLOCK_PROG, "lockstep.py": LABLOCK_LOCKSTEP}
    yield from registered(monkeypatch, tmp_path / "site", "lablock", files)


def test_an_external_package_runs_in_lockstep_through_its_registration(lablock, tmp_path):
    path = cell_text(tmp_path, "lockcell", LOCK_SUBUNITS).read_text().replace("enabled = true", "enabled = false")
    (tmp_path / "lockcell.toml").write_text(path)
    with build_lockstep_cell(tmp_path / "lockcell.toml") as lc:
        assert sorted(lc.subunits) == ["arm1", "c1", "c2"]
        lc.run_for(1.0)
        assert lc.sched.tasks["c1.lablock"].rate_hz == 40.0  # its declared rate
        for n in ("c1", "c2"):  # cycles at t = 0, 25 ms, ..., 1 s; the reply of the tick at 1 s carries them
            st = lc.subunits[n].status.read()
            assert int(st["tick"]) == 60 and int(st["stale"]) == 0 and int(st["count"]) == 41
        assert int(lc.subunits["arm1"].status.read()["tick"]) == 60


def test_a_class_without_a_lockstep_builder_is_one_line(lab, tmp_path):
    p = cell_text(tmp_path, "labcell", LAB_SUBUNIT).with_name("labcell.toml")
    p.write_text(p.read_text().replace("enabled = true", "enabled = false"))
    with pytest.raises(BadInput) as exc:
        build_lockstep_cell(p)
    msg = str(exc.value)
    assert msg == (f"{p}: [subunits.lab1] class 'labsensor' has no lockstep builder (package 'labsensor' "
                   f"registers none in its lockstep slot)")


@pytest.mark.parametrize("slot, words", [
    ("lablock.nowhere:build", ["cannot load its lockstep builder lablock.nowhere:build", "ModuleNotFoundError"]),
    ("lablock.prog:main", ["its lockstep slot lablock.prog:main is not a builder"]),
])
def test_a_slot_that_names_no_builder_is_one_line(lablock, tmp_path, monkeypatch, slot, words):
    import dataclasses

    reg = R.registry()
    monkeypatch.setitem(reg.packages, "lablock", dataclasses.replace(reg.packages["lablock"], lockstep=slot))
    (tmp_path / "c.toml").write_text(cell_text(tmp_path, "lockcell", LOCK_SUBUNITS).read_text()
                                     .replace("enabled = true", "enabled = false"))
    with pytest.raises(BadInput) as exc:
        build_lockstep_cell(tmp_path / "c.toml")
    msg = str(exc.value)
    assert msg.startswith(f"{tmp_path / 'c.toml'}: [subunits.c1] package 'lablock': ") and "\n" not in msg
    assert all(w in msg for w in words), msg
