"""The force task's lockstep trial (issue 27 item 5): the full Reis arm holds 20 N on the step
workpiece's flat face while sliding, through the contact model and the F/T twin."""
from __future__ import annotations

import csv

import pytest

from droid.experiments.contact_trial import COLUMNS, ContactTrialConfig, run_contact_trial, write_csv


def test_a_short_trial_holds_the_normal_force_and_ends_its_path(tmp_path):
    res = run_contact_trial(ContactTrialConfig(length_mm=30.0, seed=2))
    assert res.stop == "end", res.summary
    assert res.summary.startswith("normal force RMS error ")
    assert res.rms_n < 1.0 and res.max_n < 3.0, res.summary
    path = [r for r in res.rows if r[1] == "path"]
    assert path[-1][7] == pytest.approx(30.0, abs=1.0)  # the true tool travelled the path
    assert all(r[4] > 10.0 for r in path)  # the true contact held throughout
    write_csv(str(tmp_path / "t.csv"), res.rows)
    with open(tmp_path / "t.csv") as f:
        rows = list(csv.reader(f))
    assert tuple(rows[0]) == COLUMNS and len(rows) == len(res.rows) + 1
