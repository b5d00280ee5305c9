"""A fourth arm family runs a seam-tracking trial in lockstep with no edit outside its package (issue 43).

``labarm``, a lab's small 6R arm, is written into tmp_path as a package outside the repository and
registered through a dist-info ``entry_points.txt`` (as ``labsensor`` and ``lablock`` are,
tests/registry/test_registry.py, test_lockstep_slot.py).  Everything it has is its own: its robot file
(``labarm_6r.toml``), its controller and twin (``labarm/twin.py``: joints that follow the planner's
way-point through a first-order lag at its servo's rate, homed at once by absolute encoders) and its
lockstep builder (``labarm/lockstep.py``), which reuses only what is neutral -- the Brain side every
arm shares (droid.sim.arm_chain: droid-remote, droid-agent, the neutral arm's droid-planner) -- and
never a Reis, GMF1 or ABB module.  A cell file names it as the layout's ``tool_robot`` beside the
bundled GMF1 holder; the trial (droid.experiments.trial.run_trial) picks it by that role and tracks
the seam to its end.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from droid.brain.cell.cellfile import BUNDLED_CELLS
from droid.experiments.trial import TrialConfig, run_trial
from tests.registry.test_registry import device_imports, registered

ROBOTS = Path(__file__).resolve().parents[2] / "droid" / "kinematics" / "robots"

LABARM_DEVICE = '''
"""labarm: a lab's small 6R arm (serves arm6r), its controller program and its lockstep builder."""
from droid.brain.cell.registry import DevicePackage, Program

PACKAGE = DevicePackage(
    name="labarm",
    description="a lab's 6R arm: its controller takes joint way-points, absolute encoders",
    serves=("arm6r",),
    programs=(Program("droid-labarm", "labarm.prog", rate_hz=250.0),),
    lockstep="labarm.lockstep:build",
)
'''

LABARM_PROG = '''
def main(argv=None):
    return 0
'''

LABARM_TWIN = '''
"""The lab arm's controller and arm: each servo period the joints close on the planner's way-point
(encoder_cmd_int) with time constant LAG_S; absolute encoders, so HOME is acknowledged at once."""
import math

import numpy as np

from droid.brain.db.layouts import CMD_OK, HOME_MODE, HOMED, NORMAL_MODE

LAG_S = 0.02


class LabController:
    def __init__(self, model, rate_hz, seed):
        self.model = model
        self.q = np.random.default_rng(seed).uniform(-3.0, 3.0, 6)  # power-up joints [deg]
        self.decay = math.exp(-1.0 / (rate_hz * LAG_S))
        self.homed = False
        self.home_id = None

    def cycle(self, ctrl_command, ctrl_status, t_ns):
        cmd = ctrl_command.read()
        mode, cmd_id = int(cmd["cmd_mode"]), int(cmd["cmd_id"])
        gearing = self.model.gearing
        if mode == NORMAL_MODE and self.homed:
            ref = gearing.counts_to_joints(np.asarray(cmd["encoder_cmd_int"], float))
            self.q = ref + (self.q - ref) * self.decay
        status = {"cmd_mode": mode, "coord": int(cmd["coord"]), "updated_ns": t_ns,
                  "encoder_pos": np.rint(gearing.joints_to_counts(self.q)).astype(np.int32)}
        if mode == HOME_MODE and cmd_id != self.home_id:
            self.homed, self.home_id = True, cmd_id
            status.update(cmd_id=cmd_id, cmd_result=CMD_OK, busy=0)
        status["homed"] = HOMED if self.homed else 0
        ctrl_status.update(**status)

    def wcp_global(self):
        return self.model.fk(self.q)
'''

LABARM_LOCKSTEP = '''
"""The lab arm in lockstep: the Brain side every arm shares plus its own controller twin."""
from droid.kinematics import load_robot
from droid.kinematics.transforms import pose_to_T
from droid.sim.arm_chain import ArmChain
from droid.sim.lockstep import ORDER_DEVICE
from droid.sim.lockstep_build import AGENT, LockstepSubunit, builds

from labarm.twin import LabController


class LabArm(ArmChain):
    def __init__(self, sched, name, model, stale_ticks, rate_hz, seed):
        self._make_chain(sched, name, model, stale_ticks)
        self.alive = {"link": True, "planner": True}
        self.controller = LabController(model, rate_hz, seed)
        sched.every(rate_hz, self._servo, f"{name}.labarm", order=ORDER_DEVICE)
        self._start_chain()

    def _servo(self, t_ns):
        self.controller.cycle(self.ctrl_command, self.ctrl_status, t_ns)

    def wcp_global(self):
        return self.controller.wcp_global()


@builds("droid-labarm", AGENT, "droid-planner", truth=True)
def build(ctx, sub):
    model = load_robot(sub.robot).with_base(pose_to_T(*sub.base))
    arm = LabArm(ctx.sched, sub.name, model, ctx.cell.stale_ticks, ctx.rate_hz("droid-labarm"), ctx.seed)
    n = sub.name
    stations = {"droid-labarm": [f"{n}.labarm"], AGENT: [f"{n}.tick"], "droid-planner": [f"{n}.tick"]}
    return LockstepSubunit(n, sub.cls, arm.brain_status, arm.brain_command, stations, arm, arm)
'''

LAB_SUBUNIT = '''[subunits.lab]
class = "arm6r"
robot = "{robot}"
description = "the lab's 6R arm (welding robot)"
host = "lab"
agent = "ipc://{{run}}/lab.agent"
relay = "ipc://{{run}}/lab.relay"
base = [0.0, 0.0, 0.0, 0.0, 0.0, 0.0]
programs = ["droid-agent", "droid-planner", "droid-labarm"]

'''


def _table(text: str, head: str) -> tuple[int, int]:
    """Where TOML table ``head`` starts in ``text`` and where the next table starts."""
    i = text.index(head)
    j = text.find("\n[", i + len(head))
    return i, (len(text) if j < 0 else j + 1)


def lab_cell(tmp_path: Path) -> Path:
    """The bundled ABB welding cell with the lab's arm as its welder: its own robot file, its own
    layout (the ABB layout's frames, ``tool_robot = "lab"``), the cell's GMF1 as the holder."""
    robot = tmp_path / "labarm_6r.toml"
    robot.write_text((ROBOTS / "abb_irb2400.toml").read_text().replace('name = "abb_irb2400"', 'name = "labarm_6r"'))
    layout = (BUNDLED_CELLS / "abb_weld_layout.toml").read_text()
    for old, new in (('tool_robot = "abb"', 'tool_robot = "lab"'), ('\nabb = "abb_irb2400"', f'\nlab = "{robot}"'),
                     ("\nabb = [", "\nlab = [")):
        assert old in layout, old
        layout = layout.replace(old, new)
    (tmp_path / "lab_layout.toml").write_text(layout)
    cell = (BUNDLED_CELLS / "abb_weld.toml").read_text()
    for head in ("[world.devices.abb]", "[subunits.abb]"):
        i, j = _table(cell, head)
        cell = cell[:i] + (LAB_SUBUNIT.format(robot=robot) if head == "[subunits.abb]" else "") + cell[j:]
    cell = cell.replace('layout = "abb_weld_layout.toml"', f'layout = "{tmp_path / "lab_layout.toml"}"')
    cell = cell.replace('name = "abbweld"', 'name = "labweld"')
    path = tmp_path / "lab_weld.toml"
    path.write_text(cell)
    return path


@pytest.fixture
def labarm(tmp_path, monkeypatch):
    files = {"device.py": LABARM_DEVICE, "prog.py": LABARM_PROG, "twin.py": LABARM_TWIN, "lockstep.py": LABARM_LOCKSTEP}
    yield from registered(monkeypatch, tmp_path / "site", "labarm", files)


def test_the_lab_arm_uses_no_other_arm_familys_code(labarm):
    assert device_imports(labarm) == {}


def test_a_fourth_arm_family_tracks_a_seam_in_lockstep(labarm, tmp_path):
    from droid.sim.trial_cell import resolve_trial_cell

    cell = lab_cell(tmp_path)
    tc = resolve_trial_cell(str(cell))
    assert tc.layout.tool_robot == "lab" and tc.welder_package == "labarm"  # picked by its role
    cfg = TrialConfig("lab", "i", 16.0, cell=str(cell), mode="plus", length_mm=150.0, sensor="ideal")
    r = run_trial(cfg)
    assert r.stop_reason.startswith("end of seam"), (r.stop_reason, r.stop_detail)
    assert 148.0 <= r.stop_s_mm <= 155.0
    s, lat = r.column("s_mm"), r.column("tool_lateral_mm")
    on = (s > 110.0) & np.isfinite(lat)
    assert on.sum() > 20 and np.max(np.abs(lat[on])) < 0.5  # [mm]
