"""The lockstep trial on a cell file (droid.sim.trial_cell): TrialConfig.cell, droid-experiment
run --cell FILE and a plan's cell key -- the ABB welding cell's trial, the Reis's on sim.toml, and
bad cells (one line, exit 2)."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from droid.cli import BadInput
from droid.experiments.cli import main
from droid.experiments.plan import plan_from_dict
from droid.experiments.trial import TrialConfig, run_trial

CELLS = Path(__file__).resolve().parents[2] / "droid" / "cells"
ABB = CELLS / "abb_weld.toml"


def _exit_code(fn):
    try:
        return fn()
    except SystemExit as exc:
        return exc.code


def test_the_abb_trial_tracks_to_the_end_of_the_seam():
    """150 mm in plus mode at 16 mm/s from (i): the ABB (droid-egm and its controller twin) homes,
    moves to the start and tracks; the tool stays on the seam after the lead sensor's 100 mm."""
    cfg = TrialConfig("abb", "i", 16.0, cell=str(ABB), mode="plus", length_mm=150.0, sensor="ideal")
    r = run_trial(cfg)
    assert r.stop_reason.startswith("end of seam"), (r.stop_reason, r.stop_detail)
    assert 148.0 <= r.stop_s_mm <= 155.0
    s, lat = r.column("s_mm"), r.column("tool_lateral_mm")
    on = (s > 110.0) & np.isfinite(lat)
    assert on.sum() > 20 and np.max(np.abs(lat[on])) < 0.5  # [mm]


def test_the_reis_on_sim_toml_is_the_trial_without_a_cell():
    """--cell cells/sim.toml names what the trial uses without one: the same log, to the bit."""
    cfg = TrialConfig("1", "i", 16.0, mode="plus", length_mm=60.0, sensor="ideal")
    plain = run_trial(cfg)
    on_cell = run_trial(TrialConfig("1", "i", 16.0, mode="plus", length_mm=60.0, sensor="ideal",
                                    cell=str(CELLS / "sim.toml")))
    assert len(plain.rows) > 20 and plain.stop_reason.startswith("end of seam")
    assert repr(plain.rows) == repr(on_cell.rows)


def test_run_cell_prints_its_summary_line(tmp_path, capsys):
    out = tmp_path / "exp"
    code = main(["run", "1.3", "--cell", str(ABB), "--mode", "plus", "--length", "150", "--no-figures",
                 "--jobs", "1", "--out", str(out)])
    assert code == 0
    line = capsys.readouterr().out.strip().splitlines()
    assert len(line) == 1 and line[0].startswith("1.3: ") and "end of seam" in line[0]
    assert (out / "table6.1" / "1.3.csv").is_file()


def _variant(tmp_path, name: str, old: str, new: str) -> Path:
    text = ABB.read_text()
    assert old in text
    p = tmp_path / name
    p.write_text(text.replace(old, new))
    return p


def _bad_cells(tmp_path) -> list[tuple[list, list]]:
    """(extra argv, what the one line must name) of each bad --cell."""
    renamed = _variant(tmp_path, "renamed.toml", "[subunits.abb]", "[subunits.welder]")
    no_egm = _variant(tmp_path, "no_egm.toml", 'programs = ["droid-reis-agent", "droid-planner", "droid-egm"]',
                      'programs = ["droid-reis-agent", "droid-planner"]')
    return [
        (["--cell", str(tmp_path / "missing.toml")], ["cell file not found", "missing.toml"]),
        (["--cell", str(renamed)], [str(renamed), "tool_robot 'abb'", "does not have"]),
        (["--cell", str(no_egm)], [str(no_egm), "[subunits.abb]", "no lockstep arm", "droid-egm"]),
        (["--cell", str(ABB), "--arm", "fast"], [str(ABB), "[subunits.abb]", "fast"]),
        (["--cell", str(ABB), "--realtime"], ["--realtime"]),
    ]


def test_bad_cells_exit_2_with_one_line(tmp_path, capsys):
    for extra, named in _bad_cells(tmp_path):
        out = tmp_path / "out"
        argv = ["run", "1.3", "--out", str(out), *extra]
        assert _exit_code(lambda argv=argv: main(argv)) == 2, extra
        err = capsys.readouterr().err
        assert len(err.strip().splitlines()) == 1 and "Traceback" not in err, err
        for word in named:
            assert word in err, (word, err)
        assert not out.exists()  # nothing ran, nothing written


def test_a_plan_cell_key_runs_its_trials_on_that_cell(tmp_path):
    plan = {"name": "abb", "cell": "abb_weld.toml", "defaults": {"length_mm": 100.0}, "sweep": {"seed": [1, 2]}}
    p = plan_from_dict(plan, "plan.toml", tmp_path)
    assert [t.config.cell for t in p.trials] == [str(ABB)] * 2
    assert all(t.params["cell"] == "abb_weld.toml" for t in p.trials)
    plain = plan_from_dict({k: v for k, v in plan.items() if k != "cell"}, "plan.toml", tmp_path)
    assert {t.id for t in p.trials}.isdisjoint(t.id for t in plain.trials)  # the cell is in the ID
    assert all(t.config.cell is None and "cell" not in t.params for t in plain.trials)
    (tmp_path / "sub").mkdir()
    mine = _variant(tmp_path / "sub", "mine.toml", 'name = "abbweld"', 'name = "mine"')
    rel = plan_from_dict({**plan, "cell": "sub/mine.toml"}, "plan.toml", tmp_path)  # relative to the plan
    assert rel.trials[0].config.cell == str(mine.resolve())


@pytest.mark.parametrize("plan, named", [
    ({"cell": "nowhere.toml"}, "cell file not found"),
    ({"cell": 3}, "must be a cell file"),
    ({"cell": "abb_weld.toml", "sweep": {"arm": ["full", "fast"]}}, "fast arm model"),
    ({"cell": "abb_weld.toml", "trial": "contact"}, "seam-tracking plans only"),
])
def test_a_bad_plan_cell_is_one_line_naming_the_plan(plan, named, tmp_path):
    with pytest.raises(BadInput) as exc:
        plan_from_dict({"name": "p", **plan}, "my_plan.toml", tmp_path)
    msg = str(exc.value)
    assert msg.startswith("plan my_plan.toml:") and named in msg and "\n" not in msg, msg
