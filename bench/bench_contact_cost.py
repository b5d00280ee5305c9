#!/usr/bin/env python3
"""CPU cost of the world's contact per plant step: ``ToolContact.joint_torque`` (issue 27 item 4).

droid-sim steps the world at 1 kHz in Python; the contact device asks its ``ToolContact`` at
each step of the tool arm's plant.  This prints, for each case, the mean time of one call
[us of this process's CPU time, not wall time: a shared host's other processes
disturb it less] (skipped calls included) and how many of the calls were asked in full, with the skip
(``max_closing_speed_mm_s`` 5000 mm/s, plates 5 mm: the contact device's defaults) and
without it (every call asked in full, as the lockstep trials do), and the surface's answer
alone (``surface_contact``: the geometry and the law, without the arm's kinematics).  It
decides nothing.

Cases (the Reis plant at power-up, its tool point 250 mm out, held still; the workpiece
placed so that the point is where the case says, in the workpiece frame):

* plane, wall: step_input, 0.3 mm into the step's wall, 1 mm above the lower plate;
* plane, top: step_input, 0.5 mm into the lower plate, 25 mm beside the seam;
* plane, near: 13 mm above the lower plate (seam tracking's nozzle);
* plane, far: 200 mm above;
* 3-D, wall / top: cad_curve (rolled 20 deg at s = 400 mm, a [contact] table added),
  the same places in its local frame;
* 3-D, near: 13 mm above the rolled lower surface; 3-D, far: 200 mm above it.

Run it against another checkout (``PYTHONPATH=/other/tree``) to compare; a tree without
3-D contact prints ``refused`` for those cases.

Usage: bench/bench_contact_cost.py [--calls 150] [--repeat 40]
"""
from __future__ import annotations

import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

if "PYTHONPATH" not in os.environ:
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from droid.cli import ArgumentParser, BadInput, bounded_int
from droid.kinematics.transforms import trans
from droid.sim.contact import ToolContact, surface_contact
from droid.sim.reis.plant import ReisPlant, ReisPlantParams
from droid.sim.workpiece import WORKPIECE_DIR, load_workpiece

DT_S = 0.001
T_TOOL = trans(0.0, 0.0, 250.0)


def _cad_curve(tmp: Path):
    for f in WORKPIECE_DIR.glob("cad_curve*"):
        shutil.copy(f, tmp / f.name)
    path = tmp / "cad_curve.toml"
    path.write_text(path.read_text() + "\n[contact]\n")
    return load_workpiece(str(path))


def _cases_plane():
    plane = load_workpiece("step_input")
    yield "plane, wall", plane, np.array([30.0, 0.3, 1.0])
    yield "plane, top", plane, np.array([30.0, -25.0, -0.5])
    yield "plane, near (13 mm above)", plane, np.array([30.0, -25.0, 13.0])
    yield "plane, far (200 mm above)", plane, np.array([30.0, -25.0, 200.0])


def _cases(tmp: Path):
    yield from _cases_plane()
    wp = _cad_curve(tmp)
    p, _, n, l = wp.seam.point_frame(400.0)
    yield "3-D, wall", wp, p + 0.3 * l + 1.0 * n
    yield "3-D, top", wp, p - 25.0 * l - 0.5 * n
    yield "3-D, near (13 mm above)", wp, p - 25.0 * l + 13.0 * n
    yield "3-D, far (200 mm above)", wp, p - 25.0 * l + 200.0 * n


def measure(contact, plant, q, qd, calls: int, repeat: int) -> tuple[float, float, float]:
    """(min and median over ``repeat`` blocks of the mean us per call in a block of ``calls``,
    fraction of the calls asked in full).  The minimum is the figure least disturbed by
    other processes on a shared host."""
    means = []
    e0 = contact.evaluations
    for _ in range(repeat):
        contact._skip_s = 0.0
        t0 = time.process_time()
        for _ in range(calls):
            contact.joint_torque(plant.body, q, qd, DT_S)
        means.append((time.process_time() - t0) / calls * 1e6)
    return min(means), float(np.median(means)), (contact.evaluations - e0) / (calls * repeat)


def measure_surface(wp, T_W, p, v, calls: int, repeat: int) -> tuple[float, float]:
    """(min, median) us of the surface's answer alone (surface_contact: the geometry and the law)."""
    means = []
    for _ in range(repeat):
        t0 = time.process_time()
        for _ in range(calls):
            surface_contact(wp, T_W, p, v, wp.contact)
        means.append((time.process_time() - t0) / calls * 1e6)
    return min(means), float(np.median(means))


def main(argv=None) -> int:
    ap = ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--calls", type=bounded_int(1, 10**6, "calls"), default=150, help="calls per timed block")
    ap.add_argument("--repeat", type=bounded_int(1, 10**4, "blocks"), default=40, help="timed blocks per case")
    args = ap.parse_args(argv)
    plant = ReisPlant(ReisPlantParams(), seed=4)
    probe = ToolContact(load_workpiece("step_input"), trans(0.0, 0.0, -5000.0), np.eye(4), T_TOOL)
    plant.contact = probe
    plant.advance(0.002)
    p_tool = probe.tool_mm.copy()
    q = plant._q.copy()
    qd = np.array([0.002, -0.001, 0.001, 0.003, -0.002, 0.001])  # a slow slide: friction acts
    print(f"load average {os.getloadavg()[0]:.2f} {os.getloadavg()[1]:.2f} {os.getloadavg()[2]:.2f}; "
          f"{args.repeat} blocks of {args.calls} calls; us per call, min / median of the blocks' means")
    with tempfile.TemporaryDirectory() as d:
        try:
            cases = list(_cases(Path(d)))
        except BadInput as exc:  # a tree without 3-D contact refuses the table
            cases = list(_cases_plane())
            print(f"3-D cases refused: {exc}")
        for name, wp, x_W in cases:
            T_W = trans(*(p_tool - x_W))
            out = []
            for closing in (5000.0, None):
                try:
                    c = ToolContact(wp, T_W, np.eye(4), T_TOOL, max_closing_speed_mm_s=closing, max_depth_mm=5.0)
                except ValueError as exc:
                    out.append(f"refused ({exc})")
                    break
                lo, med, frac = measure(c, plant, q, qd, args.calls, args.repeat)
                touching = "touching" if c.force_N.any() else "apart"
                out.append(f"{'skip' if closing else 'every'} {lo:6.1f} / {med:6.1f} us ({frac:.0%} asked, {touching})")
            lo, med = measure_surface(wp, T_W, p_tool, c.tool_v_mm_s, args.calls, args.repeat)
            out.append(f"surface {lo:5.1f} / {med:5.1f} us")
            print(f"{name:26s} " + "; ".join(out), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
