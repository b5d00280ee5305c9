"""A lab's own seam sensor is a trial's lead sensor with no edit outside its package (issue 43 item 3).

``labseam``, a lab's line-laser seam sensor, is written into tmp_path as a package outside the
repository and registered through a dist-info ``entry_points.txt`` (as ``labsensor`` and ``labarm``
are, tests/registry/test_registry.py, test_fourth_arm.py).  It serves the Brain's ``line_laser``
class, as the MVS does, and registers the trial's truth sensors as its ``lead`` lockstep model
(``DevicePackage.lockstep_models``): an ``ideal`` sensor that sees the seam exactly through the
workpiece's own geometry (droid.sim.seam3d, ``Workpiece.seam``), with the tool-tip sensor beside it
-- never an MVS module.  A cell file names a subunit of it as the layout's ``sensor``, beside the
cell's MVS; the trial (droid.experiments.trial.run_trial) makes its sensors by that role, reads
every frame from the lab's sensor, and tracks the seam to its end.  ``labsensor`` (a force probe of
a class of its own) is no seam sensor, so it is not the one asked to be.
"""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from droid.brain.cell.cellfile import BUNDLED_CELLS
from droid.cli import BadInput
from droid.experiments.trial import TrialConfig, run_trial
from tests.registry.test_fourth_arm import _table
from tests.registry.test_registry import device_imports, registered

LABSEAM_DEVICE = '''
"""labseam: a lab's line-laser seam sensor (serves line_laser) and a trial's truth sensors of it."""
from droid.brain.cell.registry import DevicePackage, Program

PACKAGE = DevicePackage(
    name="labseam",
    description="a lab's line-laser seam sensor",
    serves=("line_laser",),
    programs=(Program("droid-labseam", "labseam.prog", rate_hz=30.0),),
    lockstep_models=(("lead", "labseam.trial:LabLead"),),
)
'''

LABSEAM_PROG = '''
def main(argv=None):
    return 0
'''

LABSEAM_TRIAL = '''
"""The lab sensor in a trial: the seam seen exactly from the sensor's frame (no noise)."""
from droid.brain.plumbing.sensor_line import LineReading


class LabTool:
    """The tool-tip sensor beside the lab's sensor: the exact geometry at the tool frame."""

    def __init__(self, seam):
        self.seam = seam

    def read(self, T_W_tool):
        return self.seam.measure(T_W_tool)

    truth = read


class LabLead:
    models = ("ideal",)
    made = []  # every one a trial made (the test reads them)

    def __init__(self, workpiece, model, noise=None, seed=0, frames_per_read=1):
        self.seam = workpiece.seam
        self.frames = self.valid = 0
        LabLead.made.append(self)

    def read(self, T_W_S):
        self.frames += 1
        m = self.seam.measure(T_W_S)
        if m is None:
            return LineReading(valid=False)
        self.valid += 1
        return LineReading(True, round(m.height_mm, 3), round(m.lateral_mm, 3), round(m.roll_rad, 5))

    def tool_tip(self, noisy=True, seed=0):
        return LabTool(self.seam)
'''

LAB_SUBUNIT = '''[subunits.seam]
class = "line_laser"
description = "the lab's seam sensor (lead sensor)"
host = "mvs"
link = "serial"
serial = "{run}/seam.brain.tty"
baud = 19200
programs = ["droid-labseam"]

'''


def lab_cell(tmp_path: Path) -> Path:
    """The built-in cell with the lab's sensor beside the MVS, and a layout naming it the ``sensor``."""
    layout = (BUNDLED_CELLS / "seamtrack_layout.toml").read_text()
    assert '\nsensor = "mvs"' in layout
    (tmp_path / "lab_layout.toml").write_text(layout.replace('\nsensor = "mvs"', '\nsensor = "seam"'))
    cell = (BUNDLED_CELLS / "sim.toml").read_text()
    i, _ = _table(cell, "[subunits.mvs]")
    cell = cell[:i] + LAB_SUBUNIT + cell[i:]
    cell = cell.replace('name = "sim"\n', f'name = "labseam"\nlayout = "{tmp_path / "lab_layout.toml"}"\n', 1)
    path = tmp_path / "lab_seam.toml"
    path.write_text(cell)
    return path


@pytest.fixture
def labseam(tmp_path, monkeypatch):
    files = {"device.py": LABSEAM_DEVICE, "prog.py": LABSEAM_PROG, "trial.py": LABSEAM_TRIAL}
    yield from registered(monkeypatch, tmp_path / "site", "labseam", files)


def test_the_lab_sensor_uses_no_device_packages_code(labseam):
    assert device_imports(labseam) == {}


def test_the_layouts_sensor_role_picks_the_trial_sensors(labseam, tmp_path):
    from droid.sim.trial_cell import resolve_trial_cell

    assert resolve_trial_cell().sensor_package == "mvs"  # the built-in cell: its MVS
    tc = resolve_trial_cell(str(lab_cell(tmp_path)))
    assert tc.layout.sensor == "seam" and tc.sensor_package == "labseam"  # picked by its role
    assert tc.lead_sensor("ideal").__module__ == "labseam.trial"
    with pytest.raises(BadInput, match=r"\[subunits.seam\] has no camera sensor model: package 'labseam'"):
        tc.lead_sensor("camera")


def test_a_lab_seam_sensor_leads_a_trial_in_lockstep(labseam, tmp_path):
    cfg = TrialConfig("lab", "i", 16.0, cell=str(lab_cell(tmp_path)), arm="fast", holder="fixed", mode="plus",
                      length_mm=150.0, sensor="ideal")
    r = run_trial(cfg)
    made = sys.modules["labseam.trial"].LabLead.made
    assert len(made) == 1 and r.frames == made[0].frames > 100 and r.valid_frames == made[0].valid  # its frames
    assert r.stop_reason.startswith("end of seam"), (r.stop_reason, r.stop_detail)
    assert 148.0 <= r.stop_s_mm <= 155.0
    s, lat = r.column("s_mm"), r.column("tool_lateral_mm")
    on = (s > 110.0) & np.isfinite(lat)
    assert on.sum() > 20 and np.max(np.abs(lat[on])) < 0.5  # [mm]
