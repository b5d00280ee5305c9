"""droid-calibrate: the optical calibration of thesis §4.1.1.4 on the simulated cell (lockstep).

    droid-calibrate ROBOT [--cell FILE] [--seed N] [--no-write]

"An LED laser is placed in the center of the tool face of the robot and a
sequence of moves and measurements are performed to determine ... the home
offsets from the limit switch positions of each joint" (§4.1.1.4).  Here the
laser sits on the tool axis (z6) at the tool face, the world renders its spot
on three screens fixed in the arm's base frame -- a wall in front of the
arm, the ceiling, the floor -- and a camera twin reads each spot (a 2 mm/px
image of a Gaussian spot with pixel noise; its centroid, :class:`SpotCamera`).
The arm is homed, then driven through the thesis's sequence:

1. near home, tool at the wall: rotate joint 6 (the laser's centring check);
2. rotate joint 4: the spot stays put only if joint 5's zero is right;
3. rotate joint 3, then joint 5: the two traces coincide only if joint 4's is;
4. links straight up, tool at the ceiling: rotate joints 1 and 4: a single
   dot only if joints 2 and 3 are right;
5. back to the perceived home, joint 5 turned 90 deg to the floor, rotate
   joint 1: the circle's radius checks joints 2 and 3 (the thesis's 1080 mm).

Instead of adjusting by eye until the spots coincide, the spot positions of
all poses are fitted at once (Gauss-Newton) for the home offsets of joints
1-5 -- joint 1's is observable because the screens are fixed in the base
frame; the thesis calls it arbitrary (the workspace centre) -- with the robot
file's kinematics and, for the drives' deflection under gravity, its
``[dynamics]`` (the controller knows its own arm's data, not the world's
errors).  Joint 6 is calibrated "using an inclinometer" (§4.1.1.4): an
inclinometer on the tool face reads the roll of the tool about the horizontal
tool axis at the home pose.

The servo frame already includes any earlier calibration (the file below), so
the fit is added to it.  The estimate ``home_offset_deg`` has the sense of the world's
``home_error_deg``: the true switch position minus the robot file's.  It is
written to ``<run_dir>/<ROBOT>.home_offset.json``, which droid-servo reads at
start (``ServoParams.from_robot(robot, home_offset_deg)``), and the lockstep arm
is re-homed with it to check.  Output: one JSON object on stdout,
``{"robot", "home_offset_deg": [6], "residual_mm", "poses", "written"}``.
Exit codes: 0; 1 the arm could not be homed or moved; 2 bad arguments or files.
"""
from __future__ import annotations

import json
import math
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from droid.cli import BadInput, RuntimeFailure, run, seed_int
from droid.subunits.reis.robot_file import offset_file

PROG = "droid-calibrate"
SETTLE_S = 0.8  # after each move, before looking for rest
MOVE_S = 2.0
#: A pose is read at rest: the spot is read every REST_DT_S until it moved less than REST_MM
#: since the last reading (the camera's centroid noise is ~0.02 mm) and no encoder moved more
#: than a count -- at most REST_MAX_S.  After the large moves (joint 3 to the ceiling pose) the
#: motors of ``reis_class_b`` still creep to their targets 0.8 s after the move (stick-slip
#: against their stiction) and the links trail them by up to 0.05 deg of dynamic deflection,
#: which the static model does not know: read then, the fit was 0.03 deg off on joints 2-3.
REST_MM = 0.1
REST_DT_S = 0.2
REST_MAX_S = 6.0


@dataclass(frozen=True)
class Screen:
    """A plane in the arm's base frame: ``origin`` [mm], unit ``normal``, in-plane axes ``u``, ``v``."""

    name: str
    origin: tuple
    normal: tuple
    u: tuple
    v: tuple

    def hit(self, p0: np.ndarray, d: np.ndarray) -> np.ndarray | None:
        """Screen coordinates [mm] where the ray p0 + t d (t > 0) meets the plane, or None."""
        n = np.asarray(self.normal, float)
        den = float(n @ d)
        if abs(den) < 1e-9:
            return None
        t = float(n @ (np.asarray(self.origin, float) - p0)) / den
        if t <= 0:
            return None
        x = p0 + t * d - np.asarray(self.origin, float)
        return np.array([x @ np.asarray(self.u, float), x @ np.asarray(self.v, float)])


SCREENS = {
    "wall": Screen("wall", (2500.0, 0.0, 0.0), (-1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0)),
    "ceiling": Screen("ceiling", (0.0, 0.0, 3500.0), (0.0, 0.0, -1.0), (1.0, 0.0, 0.0), (0.0, 1.0, 0.0)),
    "floor": Screen("floor", (0.0, 0.0, 0.0), (0.0, 0.0, 1.0), (1.0, 0.0, 0.0), (0.0, 1.0, 0.0)),
}


class SpotCamera:
    """The camera twin looking at a screen: renders the laser spot (Gaussian, ``spot_sigma_mm``)
    on a ``mm_per_px`` grid with pixel noise and returns its intensity centroid [mm]."""

    def __init__(self, seed: int = 0, mm_per_px: float = 2.0, spot_sigma_mm: float = 3.0,
                 noise: float = 0.01, window_px: int = 16) -> None:
        self.rng = np.random.default_rng(seed)
        self.mm_per_px, self.sigma, self.noise, self.w = mm_per_px, spot_sigma_mm, noise, window_px

    def read(self, spot_mm: np.ndarray) -> np.ndarray:
        c = np.floor(np.asarray(spot_mm, float) / self.mm_per_px).astype(int)
        idx = np.arange(-self.w, self.w + 1)
        pu = (c[0] + idx + 0.5) * self.mm_per_px  # pixel centres [mm]
        pv = (c[1] + idx + 0.5) * self.mm_per_px
        img = np.exp(-((pu[:, None] - spot_mm[0]) ** 2 + (pv[None, :] - spot_mm[1]) ** 2) / (2 * self.sigma ** 2))
        img = np.clip(img + self.rng.normal(0.0, self.noise, img.shape), 0.0, None)
        img = np.where(img > 0.05, img, 0.0)  # threshold the background
        s = img.sum()
        return np.array([(img.sum(axis=1) @ pu) / s, (img.sum(axis=0) @ pv) / s])


def thesis_sequence() -> list[tuple[str, tuple]]:
    """(screen, commanded joint angles [deg, the controller's frame]) of §4.1.1.4's sequence."""
    poses = []
    for q6 in (-90.0, 0.0, 90.0):  # 1. joint 6: laser centring
        poses.append(("wall", (0, 0, 0, 0, 0, q6)))
    for q4 in (-60.0, -30.0, 30.0, 60.0):  # 2. joint 4: joint 5's zero
        poses.append(("wall", (0, 0, 0, q4, 0, 0)))
    for q3 in (-10.0, 10.0):  # 3. joint 3's trace, then joint 5's: joint 4's zero
        poses.append(("wall", (0, 0, q3, 0, 0, 0)))
    for q5 in (-20.0, 20.0):
        poses.append(("wall", (0, 0, 0, 0, q5, 0)))
    for q1 in (-60.0, -30.0, 0.0, 30.0, 60.0):  # 4. links straight up: joints 1 and 4
        poses.append(("ceiling", (q1, 0, 90, 0, 0, 0)))
    for q4 in (-90.0, 90.0):
        poses.append(("ceiling", (0, 0, 90, q4, 0, 0)))
    for q1 in (-60.0, -30.0, 0.0, 30.0, 60.0):  # 5. joint 5 turned to the floor, joint 1 draws a circle
        poses.append(("floor", (q1, 0, 0, 0, -90.0, 0)))
    return poses


class Predictor:
    """What the controller expects to see: its robot file's kinematics and drive deflection."""

    def __init__(self, model) -> None:
        from droid.arm.rigid_body import RigidBody

        self.model = model.with_base(np.eye(4))
        dyn = model.dynamics
        self.body = RigidBody(model.dh, dyn)
        self.k = np.asarray(dyn.hd_stiffness_nm_per_rad, float)
        self.bal = float(dyn.balancer_moment_nm)

    def deflection_deg(self, q_deg) -> np.ndarray:
        """Static drive deflection [deg] (motor-side minus link angle) at ``q_deg``."""
        q = np.radians(np.asarray(q_deg, float))
        tau = self.body.gravity(q)
        tau[1] += self.bal * math.sin(q[1])  # the balancer takes its share of joint 2's load
        return np.degrees(tau / self.k)

    def link_deg(self, q_servo_deg, offset_deg, defl_home_deg) -> np.ndarray:
        """True link angles for the servo's estimate, given the switches' offsets (homing
        zeroed the servo at the switch edges: q = q_servo + offset + deflection at the edge
        - deflection here)."""
        q = np.asarray(q_servo_deg, float) + offset_deg + defl_home_deg
        for _ in range(2):
            q = np.asarray(q_servo_deg, float) + offset_deg + defl_home_deg - self.deflection_deg(q)
        return q

    def spot(self, screen: Screen, q_link_deg) -> np.ndarray | None:
        T = self.model.fk(q_link_deg)
        return screen.hit(T[:3, 3], T[:3, 2])


def world_spot(arm, screen: Screen) -> np.ndarray | None:
    """Where the laser really hits ``screen``: the true arm (world truth, base frame)."""
    T = arm.plant.wcp_true()
    return screen.hit(T[:3, 3], T[:3, 2])


def inclinometer_deg(T: np.ndarray) -> float:
    """Roll of the tool's x axis about the (horizontal) tool axis, from the vertical [deg]."""
    x, z = T[:3, 0], T[:3, 2]
    up = np.array([0.0, 0.0, 1.0])
    up_perp = up - (up @ z) * z
    up_perp /= np.linalg.norm(up_perp)
    return math.degrees(math.atan2(float(np.cross(up_perp, x) @ z), float(up_perp @ x)))


def _read_at_rest(arm, screen: Screen, cam: SpotCamera, screen_name: str, q_cmd) -> tuple[np.ndarray, np.ndarray]:
    """The camera's spot [mm] and the encoders [counts] once the arm is at rest (REST_MM)."""
    def look():
        truth = world_spot(arm, screen)
        if truth is None:
            raise RuntimeFailure(f"{arm.name}: the laser misses the {screen_name} at {list(q_cmd)}")
        return cam.read(truth), np.asarray(arm.status["encoder_pos"], float)

    seen, counts = look()
    waited = 0.0
    while waited < REST_MAX_S:
        arm.sched.run_for(REST_DT_S)
        waited += REST_DT_S
        seen2, counts2 = look()
        still = np.linalg.norm(seen2 - seen) < REST_MM and np.max(np.abs(counts2 - counts)) <= 1.0
        seen, counts = seen2, counts2
        if still:
            break
    return seen, counts


def calibrate_arm(arm, seed: int = 0) -> dict:
    """Home ``arm`` (a LockstepArm), run the sequence, fit; returns the result dict."""
    if not arm.home(90.0):
        raise RuntimeFailure(f"{arm.name}: homing did not finish")
    pred = Predictor(arm.model)
    edges = arm.servo.home_edge_joints_deg  # row i: the pose at joint i's switch edge
    defl_home = np.array([pred.deflection_deg(edges[i])[i] for i in range(6)])
    cam = SpotCamera(seed)
    gearing = arm.model.gearing
    meas = []
    for screen_name, q_cmd in thesis_sequence():
        counts = np.rint(gearing.joints_to_counts(np.asarray(q_cmd, float))).astype(np.int32)
        cid = arm.command_joint(counts, arm.ticks_for(MOVE_S))
        if not arm.move_done(cid, MOVE_S + 6.0):
            raise RuntimeFailure(f"{arm.name}: the move to {list(q_cmd)} did not finish")
        arm.sched.run_for(SETTLE_S)
        screen = SCREENS[screen_name]
        seen, counts = _read_at_rest(arm, screen, cam, screen_name, q_cmd)
        meas.append((screen, gearing.counts_to_joints(counts), seen))
    # joint 6 by the inclinometer, at the home pose (tool axis horizontal)
    cid = arm.command_joint(np.zeros(6, np.int32), arm.ticks_for(MOVE_S))
    arm.move_done(cid, MOVE_S + 6.0)
    arm.sched.run_for(SETTLE_S)
    _, counts = _read_at_rest(arm, SCREENS["wall"], cam, "wall", [0.0] * 6)  # (the spot only to see rest)
    incl = inclinometer_deg(arm.plant.wcp_true()) + np.random.default_rng(seed + 1).normal(0.0, 0.005)
    q_home_servo = gearing.counts_to_joints(counts)

    def residuals(off5: np.ndarray) -> np.ndarray:
        off = np.concatenate((off5, [0.0]))
        r = []
        for screen, q_servo, seen in meas:
            s = pred.spot(screen, pred.link_deg(q_servo, off, defl_home))
            r.extend((s - seen) if s is not None else (1e3, 1e3))
        return np.asarray(r)

    x = np.zeros(5)
    for _ in range(8):  # Gauss-Newton, numerical Jacobian
        r0 = residuals(x)
        J = np.empty((len(r0), 5))
        for k in range(5):
            dx = np.zeros(5)
            dx[k] = 1e-4
            J[:, k] = (residuals(x + dx) - r0) / 1e-4
        step = np.linalg.lstsq(J, -r0, rcond=None)[0]
        x = x + step
        if np.max(np.abs(step)) < 1e-6:
            break
    off = np.concatenate((x, [0.0]))
    # joint 6: the inclinometer's roll against the one the model predicts with offset 0
    q_link = pred.link_deg(q_home_servo, off, defl_home)
    T0 = pred.model.fk(q_link)
    dq = np.zeros(6)
    dq[5] = 1e-3
    slope = (inclinometer_deg(pred.model.fk(q_link + dq)) - inclinometer_deg(T0)) / 1e-3
    off[5] = (incl - inclinometer_deg(T0)) / slope
    rms = float(np.sqrt(np.mean(residuals(x) ** 2)))
    off = off + arm.home_offset_deg  # the servo already used these: the estimate is on top of them
    return {"robot": arm.name, "home_offset_deg": [round(float(v), 5) for v in off],
            "residual_mm": round(rms, 4), "poses": len(meas)}


@run
def main(argv=None) -> int:
    from droid.brain.runtime.program import open_cell, parser
    from droid.sim.lockstep import Scheduler
    from droid.sim.reis.cell import arms_from_cell

    ap = parser(PROG, "Optical calibration of an arm's home offsets (thesis §4.1.1.4) on the simulated cell.")
    ap.add_argument("robot", metavar="ROBOT", help="the arm's subunit name (e.g. arm1)")
    ap.add_argument("--seed", type=seed_int, default=None, help="world seed (default: the cell file's)")
    ap.add_argument("--no-write", action="store_true", help="print the estimate, do not write it")
    args = ap.parse_args(argv)
    cell = open_cell(args)
    sub = cell.subunit(args.robot)
    sched = Scheduler(float(cell.heartbeat_hz) if hasattr(cell, "heartbeat_hz") else 60.0)
    arms = arms_from_cell(sched, cell, args.seed)
    if sub.name not in arms:
        raise BadInput(f"{args.robot!r} has no simulated Reis arm (reis_vme world device) in {cell.path}")
    arm = arms[sub.name]
    if arm.model.dynamics is None or arm.model.dh is None:
        raise BadInput(f"{arm.model.source}: [dynamics] and [dh] are needed to calibrate")
    result = calibrate_arm(arm, seed=0 if args.seed is None else args.seed)
    written = None
    if not args.no_write:
        p = offset_file(cell, sub.name)
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_text(json.dumps({"robot": sub.robot, "home_offset_deg": result["home_offset_deg"]}) + "\n")
        written = str(p)
    result["written"] = written
    print(json.dumps(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
