"""The opt-in phase report of droid-experiment (issue 44 item 1; droid.experiments.phases):
``DROID_PHASES=1`` prints each phase boundary once, in order, to stderr; with it on or off the
trial's files are byte for byte the same and nothing else is printed differently."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from droid.experiments import phases

PROG = [sys.executable, "-m", "droid.experiments.cli"]
CONTACT_PLAN = 'name = "short_contact"\ntrial = "contact"\n[defaults]\nforce_n = 20\nspeed_mm_s = 10\nlength_mm = 25\n'


def run_cli(args, out: Path, on: bool):
    env = {k: v for k, v in os.environ.items() if k != phases.ENV}
    if on:
        env[phases.ENV] = "1"
    # a hang guard only (timing never decides)
    return subprocess.run(PROG + list(args) + ["--jobs", "1", "--out", str(out)], capture_output=True, text=True,
                          timeout=600, env=env)


def files(root: Path) -> dict:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


@pytest.mark.parametrize("kind", ["full_arm", "contact"])
def test_the_phase_report_prints_each_boundary_once_in_order_and_changes_no_file(tmp_path, kind):
    if kind == "full_arm":  # the full Reis arm: built, homed, at the start, 10 mm of seam, the figure
        args, trial = ["run", "1.12", "--seed", "1", "--length", "10"], "1.12"
    else:  # the force-control trial of a plan: 25 mm, its figure
        plan = tmp_path / "short_contact.toml"
        plan.write_text(CONTACT_PLAN)
        args, trial = ["run", "--plan", str(plan)], None
    on, off = run_cli(args, tmp_path / "on", True), run_cli(args, tmp_path / "off", False)
    assert on.returncode == 0 and off.returncode == 0, on.stderr + off.stderr
    # on: one line a boundary, in order, each once
    recs = phases.parse(on.stderr)
    assert [r["phase"] for r in recs] == list(phases.PHASES)
    assert sum(ln.startswith(phases.PREFIX) for ln in on.stderr.splitlines()) == len(phases.PHASES)
    assert all(a["t"] <= b["t"] and a["cpu_s"] <= b["cpu_s"] for a, b in zip(recs, recs[1:]))
    assert len({r["pid"] for r in recs}) == 1
    at = {r["phase"]: r for r in recs}
    assert at["main"]["trial"] is None
    ids = {r["trial"] for r in recs[1:]}
    assert len(ids) == 1 and (trial is None or ids == {trial})
    sims = [at[p]["sim_s"] for p in ("built", "homed", "approached", "ready", "tracked")]
    assert all(isinstance(s, float) for s in sims) and sims == sorted(sims)
    assert sims[1] > sims[0] and sims[4] > sims[3]  # homing and the trial take simulated time
    assert all(at[p]["sim_s"] is None for p in ("main", "trial", "figure", "done"))
    # off: no phase line; the same summary lines and the same files, byte for byte
    assert phases.PREFIX not in off.stderr
    assert on.stdout == off.stdout
    stripped = [ln for ln in on.stderr.splitlines() if not ln.startswith(phases.PREFIX)]
    assert len(stripped) == len(off.stderr.splitlines())
    on_files, off_files = files(tmp_path / "on"), files(tmp_path / "off")
    assert on_files.keys() == off_files.keys() and any(k.endswith(".png") for k in on_files)
    for k in on_files:
        assert on_files[k] == off_files[k], k


def test_the_report_is_off_unless_the_variable_is_1(monkeypatch, capsys):
    for value in (None, "0", "", "yes"):
        if value is None:
            monkeypatch.delenv(phases.ENV, raising=False)
        else:
            monkeypatch.setenv(phases.ENV, value)
        phases.mark("main")
    assert capsys.readouterr().err == ""
    monkeypatch.setenv(phases.ENV, "1")
    phases.mark("trial", trial="x")
    recs = phases.parse(capsys.readouterr().err)
    assert [(r["phase"], r["trial"], r["sim_s"]) for r in recs] == [("trial", "x", None)]
