"""A lockstep trial records the same MCAP layout as a live cell (droid-experiment run --record)."""
from __future__ import annotations

import numpy as np
import pytest

from droid.brain.db.layouts import ARM_STATUS_LAYOUT
from droid.kinematics import load_robot
from droid.observe.mcapfile import read_recording
from droid.experiments.matrix import resolve
from droid.experiments.trial import run_trial, with_overrides


@pytest.fixture(scope="module")
def recorded_trial(tmp_path_factory):
    """(config, result, MCAP path) of trial 1.3 shortened to 60 mm, recorded: run once for the
    two tests below that read its recording."""
    cfg = with_overrides(resolve(["1.3"])[0].config, length_mm=60.0)
    path = tmp_path_factory.mktemp("record") / "t.mcap"
    return cfg, run_trial(cfg, record=str(path)), path


def test_trial_recording(recorded_trial):
    cfg, res, path = recorded_trial
    plain = run_trial(cfg)
    assert res.rows == plain.rows  # recording does not change the trial
    rec = read_recording(path)
    assert rec.meta["source"] == "lockstep"
    assert set(rec.layouts()) == {("arm1", "status"), ("arm1", "command"), ("gmf1", "status"),
                                  ("mvs", "status"), ("tool", "status")}
    assert rec.layouts()[("arm1", "status")] == (ARM_STATUS_LAYOUT.name, ARM_STATUS_LAYOUT.version)
    # consecutive ticks at 60 Hz virtual time
    assert np.all(np.diff(rec.ticks) == 1) and len(rec.ticks) > 60
    assert abs((rec.t_ns[61] - rec.t_ns[1]) - 1e9) < 1e3
    # the Status pose is the FK of its encoder counts (the same record a live cell holds)
    reis = load_robot("reis_v15")
    a = rec.frames[-1]["/arm1/status"][0]
    T = reis.fk(reis.gearing.counts_to_joints(np.asarray(a["encoder_pos"], float)))
    assert np.allclose(T[:3, 3], (a["x"], a["y"], a["z"]), atol=1.0)
    # commands advance, the lead sensor reads, the seam map grows
    ids = [f["/arm1/command"][0]["cmd_id"] for f in rec.frames]
    assert ids[-1] > ids[0]
    assert any(f["/mvs/status"][0]["homed"] == 0 for f in rec.frames)
    scenes = [m for f in rec.frames for m in f.get("/scene", [])]
    seam = [ln for m in scenes for e in m["entities"] if e["id"] == "seam" for ln in e["lines"]]
    assert seam and len(seam[0]["points"]) >= 1
    names = {t["child_frame_id"] for t in rec.frames[-1]["/tf"][0]["transforms"]}
    assert {"arm1/wcp", "gmf1/wcp", "tool", "sensor", "workpiece"} <= names


def test_experiment_cli_record(tmp_path):
    from tests.brain.cellutil import droid

    # a full-arm trial with its homing: a bound on the wait, generous for a loaded host, not a verdict
    out = droid("droid.experiments.cli", "run", "1.3", "--record", "--length", "60", "--no-figures",
                "--jobs", "1", "--out", str(tmp_path), timeout=600)
    assert out.returncode == 0, out.stderr
    rec = read_recording(tmp_path / "table6.1" / "1.3.mcap")
    assert rec.meta["trial"] == "1.3" and rec.meta["source"] == "lockstep" and rec.complete
    # without --record no .mcap is written: tests/sim/test_experiment_cli.py's
    # test_one_short_trial_writes_csv_png_summary_line_and_tables lists its run's directory exactly


def test_trial_recording_carries_the_workpiece_mesh(recorded_trial):
    """A lockstep trial puts its workpiece's surfaces (droid.sim.workpiece_mesh) in the scene metadata,
    and droid-web's file source sends only the seam points a page lacks (seam_from)."""
    from droid.observe.sources import FileSource
    from droid.sim.workpiece import load_workpiece
    from droid.sim.workpiece_mesh import workpiece_mesh

    _, _, path = recorded_trial
    meta = read_recording(path).meta
    assert meta["scene"]["workpiece"] == "step_input"
    assert meta["scene"]["workpiece_mesh"] == workpiece_mesh(load_workpiece("step_input"))
    src = FileSource(str(path))
    last = len(src.snaps) - 1
    full = src.frame(last)
    n = full["geo"]["seam_n"]
    assert n > 10 and full["seam_from"] == 0 and len(full["seam"]) == n
    part = src.frame(last, n - 4)
    assert part["seam_from"] == n - 4 and part["seam"] == full["seam"][-4:]
    assert src.frame(last, n + 5)["seam_from"] == 0  # past the snapshot's seam: all of it
    assert set(full["geo"]["bodies"]) >= {"arm1", "gmf1", "torch", "bracket", "fixture"}
