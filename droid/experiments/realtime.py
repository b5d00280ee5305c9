"""One experiment trial on the real-time process cell (``droid-experiment run ID --realtime``).

The lockstep harness (:mod:`droid.experiments.trial`) runs every core on
virtual time; this module runs the same trial the way an operator would on the
cell of processes (thesis §3.4: small programs chained from a shell):

1. write a cell file for the trial: the built-in simulated cell
   (``droid/cells/sim.toml``) with a unique name, a private run directory, the
   trial's seed, and the world's workpiece, its mount on the Fanuc twin and the
   wrist's tool and sensor poses taken from the seam-tracking layout;
2. ``droid-cell up``, ``droid-home arm1 & droid-home gmf1; wait`` (both arms at once);
3. ``droid-seamtrack SPEED --start POSITION --length ... --log trial.csv`` with
   the trial's gains and transport delay;
4. ``droid-cell down`` -- always, also on failure or Ctrl-C.

The CSV the task program wrote becomes the :class:`TrialResult`; its ``s_mm``
is the tool's travel measured by the task (the lockstep log's ``s_mm`` is the
same quantity from the simulated truth).  The arm and sensor model options of
a TrialConfig do not apply: the real-time cell always runs every Reis program
and the camera chain.
"""
from __future__ import annotations

import re
import subprocess
import sys
import tempfile
import time
import uuid
from pathlib import Path

from droid.brain.cell.cellfile import builtin_cell_path, without_table
from droid.cli import RuntimeFailure
from droid.kinematics.transforms import T_to_pose
from droid.sim.trial_cell import trial_geometry
from droid.experiments.trial import ProgressLimit, TrialConfig, TrialResult, default_length_mm
from droid.tasks.seam import report
from droid.tasks.seam.report import COLUMNS

UP_TIMEOUT_S = 120.0
HOME_TIMEOUT_S = 180.0


def _pose_text(T) -> str:
    return "[" + ", ".join(f"{float(v):.6f}" for v in T_to_pose(T)) + "]"


def _replace(text: str, key: str, value: str, count: int) -> str:
    """Replace the value of every ``key = ...`` line (exactly ``count`` of them)."""
    pattern = re.compile(rf"(?m)^{re.escape(key)} = [^\n#]*?(\s*#.*)?$")
    new, n = pattern.subn(lambda m: f"{key} = {value}{m.group(1) or ''}", text)
    if n != count:
        raise RuntimeFailure(f"--realtime: the built-in cell has {n} '{key}' lines, expected {count}")
    return new


def trial_cell_text(cfg: TrialConfig, name: str, run_dir: Path, base_text: str | None = None) -> str:
    """The cell file of a real-time trial (see the module docstring)."""
    geo = trial_geometry(cfg.position, cfg.workpiece, cfg.wrist)
    text = base_text if base_text is not None else builtin_cell_path().read_text()
    if "[world.devices.touch]" in text:  # no contact in a seam-tracking trial: as in lockstep, and the
        text = without_table(text, "[world.devices.touch]")  # trial's workpiece may have no [contact]
    if "[guard]" in text:  # the guard's workpiece box is the built-in cell's (step_input); the trial's
        text = without_table(text, "[guard]")  # workpiece and poses are its own, as in lockstep
    text = _replace(text, "name", f'"{name}"\nrun_dir = "{run_dir}"', 1)
    text = _replace(text, "seed", str(int(cfg.seed)), 1)
    text = _replace(text, "workpiece", f'"{geo.workpiece.name}"', 2)
    text = _replace(text, "workpiece_mount", _pose_text(geo.T_hold6_W), 2)
    text = _replace(text, "sensor_pose", _pose_text(geo.wrist.T_wcp_sensor), 1)
    text = _replace(text, "tool_pose", _pose_text(geo.wrist.T_wcp_tool), 1)
    return text


def _run(args: list[str], timeout_s: float, what: str) -> subprocess.CompletedProcess:
    try:
        out = subprocess.run([sys.executable, "-m", *args], capture_output=True, text=True, timeout=timeout_s)
    except subprocess.TimeoutExpired:
        raise RuntimeFailure(f"--realtime: {what} did not finish within {timeout_s:g} s") from None
    return out


def _check(out: subprocess.CompletedProcess, what: str) -> None:
    if out.returncode != 0:
        last = (out.stderr.strip().splitlines() or ["(no message)"])[-1]
        raise RuntimeFailure(f"--realtime: {what} failed (exit {out.returncode}): {last}")


def _home_at_once(arms, cell_args: list[str]) -> None:
    """droid-home every arm at the same time, as ``droid-home arm1 & droid-home gmf1; wait`` in a
    cell's script (thesis §3.4): each arm homes on its own subunit; each must succeed."""
    procs = {arm: subprocess.Popen([sys.executable, "-m", "droid.tasks.home", arm, *cell_args],
                                   stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) for arm in arms}
    try:
        deadline = time.monotonic() + HOME_TIMEOUT_S
        for arm, proc in procs.items():
            try:
                _, err = proc.communicate(timeout=max(0.0, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                raise RuntimeFailure(f"--realtime: droid-home {arm} did not finish within "
                                     f"{HOME_TIMEOUT_S:g} s") from None
            _check(subprocess.CompletedProcess(proc.args, proc.returncode, "", err), f"droid-home {arm}")
    finally:
        for proc in procs.values():
            if proc.poll() is None:
                proc.kill()
                proc.wait()


def run_trial_realtime(cfg: TrialConfig, out_dir) -> TrialResult:
    """Run ``cfg`` on a cell of processes (see the module docstring).  ``out_dir``: where the
    caller keeps the trial's files (the cell's logs go away with its temporary run dir)."""
    wall0 = time.perf_counter()
    geo = trial_geometry(cfg.position, cfg.workpiece, cfg.wrist)
    length = cfg.length_mm if cfg.length_mm is not None else default_length_mm(geo)
    name = f"x{uuid.uuid4().hex[:10]}"
    with tempfile.TemporaryDirectory(prefix="droid-rt-") as tmp:
        log = Path(tmp) / "seamtrack.csv"  # the caller writes the trial's own CSV from the result
        cell = Path(tmp) / f"{name}.toml"
        cell.write_text(trial_cell_text(cfg, name, Path(tmp) / "run"))
        c = ["--cell", str(cell)]
        up = _run(["droid.brain.runtime.launcher", "up", *c], UP_TIMEOUT_S, "droid-cell up")
        try:
            _check(up, "droid-cell up")
            _home_at_once(("arm1", "gmf1"), c)
            args = ["droid.tasks.seamtrack", f"{cfg.speed_mm_s:g}", "--start", cfg.position,
                    "--length", f"{length:g}", "--yaw-gain", f"{cfg.yaw_gain:g}",
                    "--pitch-gain", f"{cfg.pitch_gain:g}", "--delay", str(cfg.delay_cycles),
                    "--delay-at", f"{cfg.delay_at_mm:g}", "--dead-zone", str(cfg.dead_zone_cycles),
                    "--lost-cycles", str(cfg.lost_cycles), "--wrist", cfg.wrist, "--log", str(log), "--quiet", *c,
                    "--mode", cfg.mode]
            # wall seconds: the lockstep trial's hard cap (the tool may follow at a small fraction of
            # the commanded speed: trial.ProgressLimit) + 60 s for the program's start and stop
            limit = ProgressLimit().cap_s(length, cfg.speed_mm_s) + 60.0
            st = _run(args, limit, "droid-seamtrack")
        finally:
            down = _run(["droid.brain.runtime.launcher", "down", *c], 60.0, "droid-cell down")
        _check(down, "droid-cell down")
        if st.returncode not in (0, 1) or not log.exists():
            _check(st, "droid-seamtrack")
        result = TrialResult(cfg, rows=report.read_csv(log), camera_to_tcp_mm=geo.camera_to_tcp_mm)
    stop = next((ln.split("stopped: ", 1)[1] for ln in st.stderr.splitlines() if "stopped: " in ln), "")
    result.stop_reason, result.stop_detail = stop.partition(" at ")[0], stop
    if result.rows:
        result.stop_s_mm = float(result.rows[-1][COLUMNS.index("s_mm")])
        result.sim_s = result.stop_t_s = float(result.rows[-1][COLUMNS.index("t_s")])
    result.wall_s = time.perf_counter() - wall0
    return result
