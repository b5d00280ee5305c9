"""Benchmark of the MVS feature extraction: detection, accuracy and time per frame.

Synthetic lap joints (droid.sim.mvs.camera.lap_joint_profile_mm: a 2 mm
square-edged step, random feature position within +-10 mm depth and +-15 mm
lateral, random roll within +-0.25 rad, either polarity) are quantised with
the camera twin's noise (sub-pixel jitter, spurious rows) and extracted.
Errors are against the geometric foot of the step:

* row error [px]   = extracted row - true row (lateral, 0.2 mm a row)
* column error [px] = extracted column - true column (depth, 0.1 mm a column)
* position error [mm] = distance in the laser plane
* a "wrong" detection is one more than 1 mm off (it should have been invalid)

A second table runs the full camera twin over the step_input workpiece
(pose -> ray casting -> frame -> extract), ground truth from the tool-tip
sensor geometry.  Timing is CPU time of ``extract`` per frame on this machine.

    PYTHONPATH=. python bench/bench_mvs.py [--frames N] [--seed S]
"""
from __future__ import annotations

import math
import platform
import time

import numpy as np

from droid.cli import ArgumentParser, bounded_int, seed_int
from droid.sim.mvs.camera import CameraNoise, MvsCamera, lap_joint_profile_mm, quantise
from droid.sim.mvs.tool_sensor import measure, pose_for_reading
from droid.sim.workpiece import load_workpiece
from droid.subunits.mvs.calibration import MvsCalibration
from droid.subunits.mvs.feature import extract

STEP_MM = 2.0
WRONG_MM = 1.0
GRID = [(j, s) for j in (0.0, 0.5, 1.0) for s in (0.0, 0.1, 0.2)]


def stats(errors: list[float]) -> tuple[float, float, float, float]:
    """RMS, 95th percentile, max and mean of |error|."""
    a = np.abs(np.asarray(errors)) if errors else np.array([np.nan])
    return float(np.sqrt(np.mean(a ** 2))), float(np.percentile(a, 95)), float(a.max()), float(np.mean(a))


def run_case(frames, calib, noise, rng, make):
    """make(rng) -> (depth profile or rows, truth (x, y, roll)); returns a result row."""
    found = wrong = 0
    rows_err, cols_err, pos_err, roll_err = [], [], [], []
    spent = 0.0
    for _ in range(frames):
        rows, (tx, ty, troll) = make(rng)
        t0 = time.perf_counter()
        f = extract(rows, calib)
        spent += time.perf_counter() - t0
        if f is None:
            continue
        found += 1
        d = math.hypot(f.x_mm - tx, f.y_mm - ty)
        if d > WRONG_MM:
            wrong += 1
        rows_err.append(f.row - calib.row_of(ty))
        cols_err.append(f.column - calib.column_of(tx))
        pos_err.append(d)
        roll_err.append(f.roll_rad - troll)
    return found / frames, wrong, stats(rows_err), stats(cols_err), stats(pos_err), stats(roll_err), spent / frames


def synthetic(calib, noise):
    def make(rng):
        x, y, roll = rng.uniform(-10, 10), rng.uniform(-15, 15), rng.uniform(-0.25, 0.25)
        side = 1.0 if rng.random() < 0.5 else -1.0
        depth = lap_joint_profile_mm(calib, x, y, roll, STEP_MM, side)
        return quantise(depth, calib, noise, rng), (x, y, roll)
    return make


def camera_twin(calib, noise):
    wp = load_workpiece("step_input")
    cam = MvsCamera(wp, calib, noise)

    def make(rng):
        s = rng.uniform(10, 690)
        pose = pose_for_reading(wp, s, rng.uniform(-10, 10), rng.uniform(-15, 15), rng.uniform(-0.25, 0.25))
        truth = measure(pose, wp)
        rows = cam.frame(pose, rng)
        return rows, (truth.height_mm, truth.lateral_mm, truth.roll_rad)
    return make


#: Issue 12 item 5 targets at 0.5 px jitter and 10 % spurious rows (figures, not test verdicts).
TARGET_NOISE = (0.5, 0.1)
TARGET_ROW_MEAN_PX, TARGET_COL_MEAN_PX, TARGET_DETECTED = 0.35, 0.2, 0.995


def table(title, frames, seed, calib, maker):
    print(f"\n### {title} ({frames} frames per row)\n")
    print("| jitter px | spurious | detected | wrong | row err px mean / RMS / p95 / max "
          "| col err px mean / RMS / p95 / max | pos err mm RMS / p95 | roll err mrad RMS | extract us/frame |")
    print("|---|---|---|---|---|---|---|---|---|")
    target = None
    for jitter, spurious in GRID:
        noise = CameraNoise(jitter, spurious)
        rng = np.random.default_rng(seed)
        det, wrong, re, ce, pe, ro, t = run_case(frames, calib, noise, rng, maker(calib, noise))
        print(f"| {jitter:.1f} | {spurious:.0%} | {det:.2%} | {wrong} | {re[3]:.3f} / {re[0]:.2f} / {re[1]:.2f} / "
              f"{re[2]:.2f} | {ce[3]:.3f} / {ce[0]:.2f} / {ce[1]:.2f} / {ce[2]:.2f} | {pe[0]:.3f} / {pe[1]:.3f} "
              f"| {ro[0] * 1e3:.2f} | {t * 1e6:.0f} |")
        if (jitter, spurious) == TARGET_NOISE:
            target = (det, re[3], ce[3])
    if target is not None:
        det, rm, cm = target
        ok = rm <= TARGET_ROW_MEAN_PX and cm <= TARGET_COL_MEAN_PX and det >= TARGET_DETECTED
        print(f"\nAt {TARGET_NOISE[0]} px jitter, {TARGET_NOISE[1]:.0%} spurious rows: mean row error {rm:.3f} px "
              f"(target <= {TARGET_ROW_MEAN_PX}), mean column error {cm:.3f} px (target <= {TARGET_COL_MEAN_PX}), "
              f"detection {det:.2%} (target >= {TARGET_DETECTED:.1%}): {'met' if ok else 'NOT met'}")


def main() -> None:
    ap = ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--frames", type=bounded_int(1, 10**7, "frames"), default=2000, help="frames to time")
    ap.add_argument("--seed", type=seed_int, default=1, help="random seed")
    args = ap.parse_args()
    calib = MvsCalibration()
    print(f"Machine: {platform.node()} {platform.machine()} {platform.processor() or ''}, "
          f"Python {platform.python_version()}, numpy {np.__version__}; {time.strftime('%Y-%m-%d')}")
    table("Synthetic lap joints", args.frames, args.seed, calib, synthetic)
    table("Camera twin over step_input", args.frames // 4, args.seed, calib, camera_twin)
    wp = load_workpiece("step_input")
    cam = MvsCamera(wp, calib, CameraNoise(0.5, 0.1))
    rng = np.random.default_rng(args.seed)
    pose = pose_for_reading(wp, 50.0, 1.0, 2.0, 0.1)
    n = 300
    t0 = time.perf_counter()
    for _ in range(n):
        cam.frame(pose, rng)
    print(f"\nCamera twin render: {(time.perf_counter() - t0) / n * 1e6:.0f} us/frame")


if __name__ == "__main__":
    main()
