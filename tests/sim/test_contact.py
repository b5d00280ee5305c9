"""Contact in the world (issue 27 item 4): the penalty law, the workpiece's [contact] table, the
Reis plant deflecting under a pressing command (lockstep), the F/T twin reading the contact."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from droid.cli import BadInput
from droid.sim.trial_cell import trial_geometry
from droid.kinematics.transforms import inv_homo, trans
from droid.sim.contact import ContactParams, ToolContact, contact_force, surface_contact
from droid.sim.ft.lockstep import LockstepFt
from droid.sim.ft.netft import SENSOR_MODELS, wrench_on_sensor
from droid.sim.lockstep import Scheduler
from droid.sim.reis.cell import LockstepArm
from droid.sim.reis.plant import ReisPlant, ReisPlantParams
from droid.sim.workpiece import load_workpiece
from droid.brain.cell.cell_layout import T_W_SEAM
from tests.refusals import refused

P = ContactParams(stiffness_n_per_mm=20.0, damping_n_s_per_mm=0.5, friction_coefficient=0.3, slip_speed_mm_s=2.0)
N = np.array([0.0, 0.0, 1.0])


def test_normal_force_is_stiffness_times_depth_plus_damping_times_rate_and_zero_apart():
    assert np.allclose(contact_force(1.5, 0.0, N, np.zeros(3), P), [0, 0, 30.0])
    assert np.allclose(contact_force(1.5, 4.0, N, np.zeros(3), P), [0, 0, 30.0 + 2.0])  # k d + c d'
    assert np.allclose(contact_force(1.5, -4.0, N, np.zeros(3), P), [0, 0, 28.0])
    assert not contact_force(0.0, 10.0, N, np.zeros(3), P).any()  # touching: nothing yet
    assert not contact_force(-2.0, 0.0, N, np.zeros(3), P).any()  # apart
    assert not contact_force(0.1, -100.0, N, np.zeros(3), P).any()  # leaving fast: never pulls


@pytest.mark.parametrize("v", [[10.0, 0, 0], [0, -50.0, 0], [3.0, 4.0, 0], [0.5, 0, 0], [1e-3, 1e-3, 0]])
def test_friction_opposes_sliding_and_never_exceeds_mu_n(v):
    f = contact_force(1.0, 0.0, N, np.array(v), P)
    fn, ft = f[2], f[:2]
    assert fn == pytest.approx(20.0)
    assert np.linalg.norm(ft) <= P.friction_coefficient * fn + 1e-12
    assert ft @ np.array(v[:2]) < 0  # against the motion
    assert abs(ft[0] * v[1] - ft[1] * v[0]) < 1e-9  # along it
    speed = np.linalg.norm(v)
    want = P.friction_coefficient * fn * min(1.0, speed / P.slip_speed_mm_s)
    assert np.linalg.norm(ft) == pytest.approx(want)
    capped = contact_force(1.0, 0.0, N, np.array(v), P, slip_limit_n=0.01)
    assert np.linalg.norm(capped[:2]) == pytest.approx(min(0.01, want))


def test_the_step_workpiece_has_a_contact_table_and_its_surfaces_push_back():
    wp = load_workpiece("step_input")
    assert wp.contact == ContactParams(20.0, 0.05, 0.3, 2.0)
    assert load_workpiece("ramp_r200").contact is None  # no table: no contact model
    T = trans(100.0, 50.0, 10.0)  # W in the global frame
    p_lower = T @ np.array([30.0, -25.0, -1.0, 1.0])  # 1 mm into the lower plate
    f, d = surface_contact(wp, T, p_lower[:3], np.zeros(3), wp.contact)
    assert d == pytest.approx(1.0) and np.allclose(f, [0, 0, 20.0])
    p_upper = T @ np.array([30.0, 25.0, 1.5, 1.0])  # 0.5 mm into the upper plate (2 mm step)
    f, d = surface_contact(wp, T, p_upper[:3], np.zeros(3), wp.contact)
    assert d == pytest.approx(0.5) and np.allclose(f, [0, 0, 10.0])
    for p in ([30.0, -25.0, 0.5], [30.0, -80.0, -1.0], [-50.0, -25.0, -1.0]):  # above, beside, before the lead-in
        f, _ = surface_contact(wp, T, (T @ np.array([*p, 1.0]))[:3], np.zeros(3), wp.contact)
        assert not f.any(), p


@pytest.mark.parametrize("table, message", [
    ("stiffness_n_per_mm = 0", "contact.stiffness_n_per_mm = 0: is outside (0, 100000] N/mm"),
    ("friction_coefficient = -0.1", "contact.friction_coefficient = -0.1: is outside [0, 2]"),
    ("damping_n_s_per_mm = nan", "contact.damping_n_s_per_mm = nan: must be a finite number"),
    ("stiffnes_n_per_mm = 3", "[contact]: unknown key 'stiffnes_n_per_mm'"),
])
def test_a_bad_contact_table_is_one_line(tmp_path, table, message):
    msg = refused(tmp_path / "w.toml", f'[[segment]]\ntype = "line"\nlength_mm = 50\n[contact]\n{table}\n',
                  lambda path: load_workpiece(str(path)))
    assert message in msg, msg


def test_a_3d_workpiece_takes_a_contact_table(tmp_path):
    path = tmp_path / "w.toml"
    path.write_text('[[segment]]\ntype = "line"\nlength_mm = 50\nrise_mm = 5\n[contact]\nstiffness_n_per_mm = 7\n')
    wp = load_workpiece(str(path))
    assert not wp.planar and wp.contact.stiffness_n_per_mm == 7.0
    assert ToolContact(wp, np.eye(4), np.eye(4), np.eye(4)).params is wp.contact  # no longer refused


# ---------------------------------------------------------------- the step's wall (issue 27 item 4)

# Deliberate copy: surface_contact before the wall, the reference the new one is held to (never import it).
def _old_surface_contact(workpiece, T_global_W, p_mm, v_mm_s, params, slip_limit=None):
    """surface_contact as it was before the wall (main 3d7fa1d): the horizontal surfaces only."""
    import math

    R = T_global_W[:3, :3]
    p_W = R.T @ (np.asarray(p_mm, float) - T_global_W[:3, 3])
    h = workpiece.surface_height(p_W[0:2])
    if h is None:
        return np.zeros(3), -math.inf
    depth = h - float(p_W[2])
    if not depth > 0.0:
        return np.zeros(3), depth
    n = R[:, 2]
    v = np.asarray(v_mm_s, float)
    vn = float(v @ n)
    vt = v - vn * n
    limit = math.inf
    if slip_limit is not None:
        speed = math.sqrt(float(vt @ vt))
        if speed > 0.0:
            limit = slip_limit(vt / speed)
    return contact_force(depth, -vn, n, vt, params, limit), depth


def _rot_T(rng) -> np.ndarray:
    """A random rigid transform (mm)."""
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    if np.linalg.det(q) < 0:
        q[:, 0] = -q[:, 0]
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = q, rng.uniform(-500.0, 500.0, 3)
    return T


def _right_handed_step():
    """step_input with its upper plate on the right (upper_sign -1)."""
    from droid.cli import read_toml
    from droid.sim.workpiece import WORKPIECE_DIR, Workpiece

    data = read_toml(WORKPIECE_DIR / "step_input.toml", "workpiece")
    data["upper_side"] = "right"
    return Workpiece.from_dict(data)


@pytest.mark.parametrize("wp", [load_workpiece("step_input"), _right_handed_step()], ids=["left", "right"])
def test_a_point_pushed_into_the_steps_wall_is_pushed_out_sideways(wp):
    """0.3 mm into the wall, 1 mm above the lower plate (2 mm step): k x 0.3 mm along
    -upper_sign l, horizontal -- not k x (2 - 1) mm up, as before the wall."""
    rng = np.random.default_rng(5)
    T = _rot_T(rng)
    us = wp.upper_sign
    for x_w in (30.0, 400.0):  # before and after the 5 deg turn
        xy, heading = wp.point_at(x_w)
        l_W = np.array([-np.sin(heading), np.cos(heading), 0.0])  # the left normal at the seam
        p_W = np.array([*xy, 1.0]) + 0.3 * us * l_W
        f, d = surface_contact(wp, T, (T @ np.r_[p_W, 1.0])[:3], np.zeros(3), wp.contact)
        assert d == pytest.approx(0.3)
        assert np.allclose(f, T[:3, :3] @ (-us * l_W) * 20.0 * 0.3, atol=1e-9), f
        assert abs(f @ T[:3, 2]) < 1e-9  # nothing up
        f_old, d_old = _old_surface_contact(wp, T, (T @ np.r_[p_W, 1.0])[:3], np.zeros(3), wp.contact)
        assert d_old == pytest.approx(1.0) and f_old @ T[:3, 2] == pytest.approx(20.0)  # the old model's push
        # sliding along the wall (along the seam and up): friction against it, in the wall's plane
        t_W = np.array([np.cos(heading), np.sin(heading), 0.0])
        v = T[:3, :3] @ (10.0 * t_W + 4.0 * np.array([0.0, 0.0, 1.0]))
        f, _ = surface_contact(wp, T, (T @ np.r_[p_W, 1.0])[:3], v, wp.contact)
        fn = T[:3, :3] @ (-us * l_W) * 6.0
        ft = f - fn
        assert np.allclose(f @ (T[:3, :3] @ (-us * l_W)), 6.0)
        assert np.linalg.norm(ft) == pytest.approx(0.3 * 6.0) and ft @ v < 0


@pytest.mark.parametrize("side, z, face, depth", [
    (0.2, 1.7, "wall", 0.2),  # nearer the wall than the top (0.3 mm below it)
    (0.4, 1.7, "top", 0.3),  # nearer the top
    (0.29, 1.7, "wall", 0.29),
    (0.31, 1.7, "top", 0.3),
    (0.1, 0.2, "wall", 0.1),  # low on the wall
    (0.5, -0.5, "top", 2.5),  # below the lower plate's level: no wall there, the top's depth
    (-0.2, 1.0, None, -1.0),  # in front of the wall (the lower side): above the lower plate
])
def test_near_the_corner_the_closest_face_wins(side, z, face, depth):
    wp = load_workpiece("step_input")
    f, d = surface_contact(wp, np.eye(4), [30.0, side, z], np.zeros(3), wp.contact)
    assert d == pytest.approx(depth)
    want = {"wall": [0.0, -20.0 * depth, 0.0], "top": [0.0, 0.0, 20.0 * depth], None: [0.0, 0.0, 0.0]}[face]
    assert np.allclose(f, want, atol=1e-9), f


def test_away_from_the_wall_the_force_is_bit_for_bit_the_old_models():
    """Random points about both plane workpieces' surfaces (random poses, velocities, a slip
    cap): wherever the wall is not the closer face, force and depth equal the old model's
    exactly (np.array_equal)."""
    rng = np.random.default_rng(27)
    touched = compared = 0
    for wp in (load_workpiece("step_input"), load_workpiece("ramp_r200"), _right_handed_step()):
        params = ContactParams(20.0, 0.05, 0.3, 2.0)
        for _ in range(1500):
            T = _rot_T(rng)
            s0 = rng.uniform(-15.0, wp.length_mm + 15.0)
            xy, heading = wp.point_at(s0)
            lat = rng.uniform(-55.0, 55.0) if rng.random() < 0.5 else rng.uniform(-1.0, 1.0)
            p_W = np.array([*(xy + lat * np.array([-np.sin(heading), np.cos(heading)])), rng.uniform(-3.0, 3.0)])
            _, lt = wp.nearest_many(p_W[None, 0:2])
            side, h = wp.upper_sign * float(lt[0]), wp.step_mm
            if 0.0 <= side and 0.0 < p_W[2] < h and side < h - p_W[2]:
                continue  # the wall's: not the old model's
            p = (T @ np.r_[p_W, 1.0])[:3]
            v = rng.normal(0.0, 20.0, 3)
            cap = float(rng.uniform(0.0, 5.0))
            new = surface_contact(wp, T, p, v, params, lambda t, cap=cap: cap)
            old = _old_surface_contact(wp, T, p, v, params, lambda t, cap=cap: cap)
            assert np.array_equal(new[0], old[0]) and np.array_equal(new[1], old[1]), (wp.name, p_W)
            compared += 1
            touched += bool(old[0].any())
    assert compared > 3500 and touched > 1000, (compared, touched)


# ---------------------------------------------------------------- 3-D workpieces

CONTACT_TABLE = "\n[contact]\nstiffness_n_per_mm = 20.0\ndamping_n_s_per_mm = 0.05\n"


def _with_contact(tmp_path, name):
    """A shipped 3-D workpiece with a [contact] table (its files copied beside it)."""
    import shutil

    from droid.sim.workpiece import WORKPIECE_DIR

    for f in WORKPIECE_DIR.glob(f"{name}*"):
        shutil.copy(f, tmp_path / f.name)
    path = tmp_path / f"{name}.toml"
    path.write_text(path.read_text() + CONTACT_TABLE)
    wp = load_workpiece(str(path))
    assert not wp.planar and wp.contact.stiffness_n_per_mm == 20.0
    return wp


def test_a_rolled_surface_pushes_along_its_rolled_normal(tmp_path):
    """cad_curve at s = 400 mm (rolled 20 deg): the lower surface, the upper one's top and the
    step's wall, each k x depth along its own normal in the seam's local frame."""
    wp = _with_contact(tmp_path, "cad_curve")
    seam = wp.seam
    p, _, n, l = seam.point_frame(400.0)
    assert n[2] < np.cos(np.radians(15.0))  # rolled: the normal is not z_W
    us = seam.upper_sign
    T = _rot_T(np.random.default_rng(8))
    R = T[:3, :3]
    cases = [
        (p - 20.0 * us * l - 1.5 * n, 1.5, n),  # 1.5 mm under the lower surface
        (p + 20.0 * us * l + (2.0 - 0.7) * n, 0.7, n),  # 0.7 mm under the top (2 mm step)
        (p + 0.3 * us * l + 1.0 * n, 0.3, -us * l),  # 0.3 mm into the wall, halfway up
        (p + 0.6 * us * l + 1.8 * n, 0.2, n),  # by the corner: the top is closer
    ]
    for x_W, depth, normal in cases:
        # the nearest point of the sampled foot is s = 400 to within its chords' tilt: 0.1 um
        f, d = surface_contact(wp, T, (T @ np.r_[x_W, 1.0])[:3], np.zeros(3), wp.contact)
        assert d == pytest.approx(depth, abs=1e-4)
        assert np.allclose(f, 20.0 * depth * (R @ normal), atol=2e-3), (f, depth)
    for x_W in (p - 20.0 * us * l + 0.5 * n, p + 20 * us * l + 2.5 * n, p + 60.0 * l, p - 60.0 * l):  # above, beside
        f, _ = surface_contact(wp, T, (T @ np.r_[x_W, 1.0])[:3], np.zeros(3), wp.contact)
        assert not f.any()


def test_a_varying_step_and_a_gap_on_a_3d_workpiece(tmp_path):
    """gaps_tacks: the step grows 2 -> 3 mm from s = 100 to 500 (2.5 mm at 300); in the gap at
    s = 250..258 the upper surface comes down to the lower one (no wall)."""
    wp = _with_contact(tmp_path, "gaps_tacks")
    seam = wp.seam
    for s, h in ((300.0, 2.5), (254.0, 0.0)):
        p, _, n, l = seam.point_frame(s)
        f, d = surface_contact(wp, np.eye(4), p + 20.0 * l + (h - 0.5) * n, np.zeros(3), wp.contact)
        assert d == pytest.approx(0.5) and np.allclose(f, 10.0 * n)
        f, d = surface_contact(wp, np.eye(4), p + 0.25 * l + (h / 2) * n, np.zeros(3), wp.contact)
        if h > 0:
            assert d == pytest.approx(0.25) and np.allclose(f, -5.0 * l)  # the wall
        else:
            assert d == pytest.approx(0.0) and not f.any()  # no wall in a gap: on the surface's level


def test_the_3d_model_is_the_plane_model_on_a_plane_workpiece():
    """One model: a plane workpiece's seam (Workpiece.seam) answered by the 3-D path gives the
    plane path's force (the wall included): to rounding on lines, to the sampled arc's chord
    error (0.16 um at 200 mm radius) on an arc."""
    from droid.sim.contact import seam_contact, surfaces_for

    rng = np.random.default_rng(3)
    for wp, tol in ((load_workpiece("step_input"), 1e-9), (load_workpiece("ramp_r200"), 2e-4),
                    (_right_handed_step(), 1e-9)):
        sf = surfaces_for(wp)
        walls = 0
        for _ in range(800):
            xy, heading = wp.point_at(rng.uniform(-15.0, wp.length_mm + 15.0))
            lat = rng.uniform(-55.0, 55.0) if rng.random() < 0.5 else rng.uniform(-1.0, 1.0)
            p = np.array([*(xy + lat * np.array([-np.sin(heading), np.cos(heading)])), rng.uniform(-3.0, 3.0)])
            v = rng.normal(0.0, 20.0, 3)
            f1, d1 = surface_contact(wp, np.eye(4), p, v, wp.contact or P)
            f2, d2, _ = seam_contact(sf, np.eye(4), p, v, wp.contact or P)
            assert np.allclose(f1, f2, rtol=0, atol=40 * tol) and (d1 == d2 or abs(d1 - d2) < tol), (p, f1, f2)
            side = wp.upper_sign * float(wp.nearest_many(p[None, 0:2])[1][0])
            walls += bool(f1.any() and 0.0 <= side < wp.step_mm - p[2] and 0.0 < p[2] < wp.step_mm)
        assert walls > 10


@pytest.mark.parametrize("name", ["cad_curve", "helix_r300", "gaps_tacks", "ramp_r25"])
def test_the_3d_frame_and_foot_search_are_the_seams(name):
    """SeamSurfaces.frame is Seam3D.point_frame, .step_mm is step_at, .nearest the exact nearest
    point of the sampled foot (against a search of every segment)."""
    from droid.sim.contact import surfaces_for

    wp = load_workpiece(name)
    seam, sf = wp.seam, surfaces_for(wp)
    rng = np.random.default_rng(1)
    for s in rng.uniform(-20.0, seam.length_mm + 20.0, 200):
        for a, b in zip(seam.point_frame(s), sf.frame(s)):
            assert np.allclose(a, b, rtol=0, atol=1e-12)
        assert sf.step_mm(s) == float(seam.step_at(s))
    P = seam.p
    D, P0 = P[1:] - P[:-1], P[:-1]
    L2 = np.where((D * D).sum(1) > 0, (D * D).sum(1), 1.0)
    for _ in range(200):
        x = P[rng.integers(1, len(P) - 1)] + rng.normal(0.0, 40.0, 3)
        a = np.clip(((x - P0) * D).sum(1) / L2, 0.0, 1.0)
        d2 = (((x - P0) - a[:, None] * D) ** 2).sum(1)
        k = int(np.argmin(d2))
        s, dist = sf.nearest(x)
        assert dist == pytest.approx(np.sqrt(d2[k]), abs=1e-9)
        assert s == pytest.approx(seam.s[k] + a[k] * (seam.s[k + 1] - seam.s[k]), abs=1e-6)


def test_the_3d_clearance_is_a_lower_bound_on_the_distance_to_a_touch(tmp_path):
    """ToolContact's skip bound on a 3-D workpiece: no point within (distance to the foot -
    reach) of a point touches (random points about cad_curve's rolled, curved surfaces)."""
    from droid.sim.contact import seam_contact

    wp = _with_contact(tmp_path, "cad_curve")
    c = ToolContact(wp, np.eye(4), np.eye(4), np.eye(4), max_closing_speed_mm_s=1000.0, max_depth_mm=5.0)
    sf, reach = c._surfaces, c._reach_mm
    assert reach == pytest.approx(np.hypot(50.0, 5.0) + 1.0)
    rng = np.random.default_rng(11)
    seam = wp.seam
    positive = 0
    for _ in range(600):
        p, _, n, l = seam.point_frame(rng.uniform(-20.0, seam.length_mm + 20.0))
        x = p + rng.uniform(-120.0, 120.0) * l + rng.uniform(-60.0, 60.0) * n
        _, _, foot = seam_contact(sf, np.eye(4), x, np.zeros(3), wp.contact, reach_mm=reach)
        clearance = foot - reach
        if clearance <= 0:
            continue
        positive += 1
        for _ in range(5):  # a point just within the clearance, toward the foot and anywhere
            u = rng.normal(size=3)
            y = x + 0.999 * clearance * u / np.linalg.norm(u)
            f, d, _ = seam_contact(sf, np.eye(4), y, np.zeros(3), wp.contact, reach_mm=reach)
            assert not (f.any() and d <= 5.0), (x, y)
    assert positive > 100


def test_a_plant_whose_tool_is_off_the_surface_steps_bit_for_bit_as_without_contact():
    wp = load_workpiece("step_input")
    plants = [ReisPlant(ReisPlantParams(), seed=4) for _ in range(2)]
    far = ToolContact(wp, trans(0.0, 0.0, -5000.0), np.eye(4), trans(0.0, 0.0, 250.0))
    plants[1].contact = far
    for _ in range(50):
        for p in plants:
            p.advance(0.002)
    assert np.array_equal(plants[0]._q, plants[1]._q) and np.array_equal(plants[0]._theta, plants[1]._theta)
    assert far.depth_mm < 0 and not far.force_N.any()


@pytest.fixture(scope="module")
def pressed():
    """The full Reis arm (lockstep) above the step workpiece's lower plate, its tool point
    commanded 1 mm above, then 2 mm into the surface; the F/T twin on its wrist."""
    geo = trial_geometry("i", "step_input")
    T_tool = geo.wrist.T_wcp_tool

    def wcp_for(z_w):
        return geo.T_global_W @ trans(20.0, -25.0, z_w) @ T_W_SEAM @ inv_homo(T_tool)

    sched = Scheduler(60.0)
    arm = LockstepArm(sched, "arm1", seed=3)
    assert arm.home(60.0)
    q0 = geo.tool.ik(wcp_for(3.0), np.zeros(6))
    cmd = arm.command_joint(np.rint(geo.tool.gearing.joints_to_counts(q0)).astype(np.int32), arm.ticks_for(4.0))
    assert arm.move_done(cmd, 9.0)
    contact = ToolContact(geo.workpiece, geo.T_global_W, geo.tool.base, T_tool)
    arm.attach_contact(contact)
    T_ws = trans(0.0, 0.0, 100.0)
    ft = LockstepFt(sched, arm, T_ws, inv_homo(T_ws) @ T_tool, seed=11)
    out = {}
    for name, z in (("above", 1.0), ("pressed", -2.0)):
        arm.command_cart(wcp_for(z), arm.ticks_for(1.0))
        sched.run_for(2.0)
        out[name] = dict(depth=contact.depth_mm, force=contact.force_N.copy(),
                         deflection=arm.plant.joint_deg - arm.plant.motor_joint_deg,
                         ft=dict(ft.fields), truth=ft.device.true_wrench(),
                         wrench=arm.contact_wrench_N_Nm(), T_gs=arm.wcp_global() @ T_ws)
    return geo, out, ft


def test_a_position_controlled_arm_pressing_into_the_surface_deflects_through_its_drives(pressed):
    geo, out, _ = pressed
    above, pr = out["above"], out["pressed"]
    assert above["depth"] < 0 and not above["force"].any()
    n = geo.T_global_W[:3, 2]
    fn = float(pr["force"] @ n)
    # commanded 2 mm in: the contact (20 N/mm) and the arm share it -- the tool goes in less than 2 mm
    assert 0.3 < pr["depth"] < 1.9
    assert fn == pytest.approx(20.0 * pr["depth"], rel=0.02)
    # the drives carry the load: the link-side angles move away from the motor side's
    change = np.abs(pr["deflection"] - above["deflection"])
    assert change.max() > 1e-3  # [deg]


def test_the_ft_twin_reads_the_contact_force_plus_the_tool_weight(pressed):
    _, out, ft = pressed
    pr = out["pressed"]
    f_c, m_c = pr["wrench"]
    assert np.linalg.norm(f_c) > 5.0
    T_st = ft.device.T_sensor_tool
    f_true, m_true = pr["truth"]
    f_want, m_want = wrench_on_sensor(pr["T_gs"], T_st, 1.5, (0.0, 0.0, 60.0), (f_c, m_c))
    assert np.allclose(f_true, f_want, atol=1e-6) and np.allclose(m_true, m_want, atol=1e-6)
    f_weight, _ = wrench_on_sensor(pr["T_gs"], T_st, 1.5, (0.0, 0.0, 60.0))
    assert np.linalg.norm(f_true - f_weight) == pytest.approx(np.linalg.norm(f_c), rel=1e-6)
    # what droid-ft's core made of the twin's records: the true wrench within 6 sigma (+ drift)
    sigma = np.array(SENSOR_MODELS["gamma"].noise)
    got = np.r_[pr["ft"]["force_N"], pr["ft"]["torque_Nm"]]
    assert pr["ft"]["valid"] == 1
    assert np.all(np.abs(got - np.r_[f_true, m_true]) < 6 * sigma + 0.02), got - np.r_[f_true, m_true]


# ---------------------------------------------------------------- contact from a cell file

SIM = Path(__file__).resolve().parents[2] / "cells" / "sim.toml"


def _cell_with(tmp_path, lines: str):
    from droid.brain.cell.cellfile import load_cell

    text = SIM.read_text().replace('[world.devices.arm1]\ntype = "reis_vme"\nsubunit = "arm1"\n',
                                   f'[world.devices.arm1]\ntype = "reis_vme"\nsubunit = "arm1"\n{lines}')
    assert lines in text
    p = tmp_path / "cell.toml"
    p.write_text(text)
    return load_cell(str(p))


def test_a_cell_puts_a_workpiece_under_the_reis_tool(tmp_path):
    from droid.sim.reis.cell import arms_from_cell
    from droid.sim.reis.world import ReisDevice

    cell = _cell_with(tmp_path, 'contact_workpiece = "step_input"\ncontact_workpiece_pose = [400, 300, 900, 0, 0, 0]\n')
    arm = arms_from_cell(Scheduler(60.0), cell)["arm1"]
    c = arm.plant.contact
    assert isinstance(c, ToolContact) and c.workpiece.name == "step_input"
    assert np.allclose(c.T_global_W[:3, 3], [400, 300, 900])
    assert np.allclose(c.T_wcp_tool[:3, 3], [0, 0, 250])  # the seam layout's tool point by default
    assert np.allclose(c.T_wcp_tool, trial_geometry("i", "step_input").wrist.T_wcp_tool)
    c.force_N = np.array([1.0, 2.0, 3.0])
    assert np.allclose(arm.contact_wrench_N_Nm()[0], [1, 2, 3])
    dev = ReisDevice("arm1", None, arm.plant, arm.model)  # droid-sim's device gives the twin the same hook
    assert np.allclose(dev.contact_wrench_N_Nm()[0], [1, 2, 3])
    arm.attach_contact(None)
    assert not dev.contact_wrench_N_Nm()[0].any()
    plain = arms_from_cell(Scheduler(60.0), _cell_with(tmp_path, ""))["arm1"]
    assert plain.plant.contact is None


@pytest.mark.parametrize("lines, message", [
    ("contact_workpiece_pose = [0, 0, 0, 0, 0, 0]\n", "contact_workpiece_pose: needs contact_workpiece"),
    ('contact_workpiece = "ramp_r200"\ncontact_workpiece_pose = [0, 0, 0, 0, 0, 0]\n', "has no [contact] table"),
    ('contact_workpiece = "step_input"\n', "needs contact_workpiece_pose"),
    ('contact_workpiece = "step_input"\ncontact_workpiece_pose = [0, 0, 1e9, 0, 0, 0]\n',
     "contact_workpiece_pose[2] = 1000000000.0: is outside"),
    ('contact_workpiece = "step_input"\ncontact_workpiece_pose = [0, 0]\n', "contact_workpiece_pose: expected a list of 6"),
])
def test_bad_contact_options_are_one_line(tmp_path, lines, message):
    from droid.sim.reis.cell import arms_from_cell

    with pytest.raises(BadInput) as exc:
        arms_from_cell(Scheduler(60.0), _cell_with(tmp_path, lines))
    assert "\n" not in str(exc.value) and message in str(exc.value), str(exc.value)
