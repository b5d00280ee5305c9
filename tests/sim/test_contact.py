"""Contact in the world (issue 27 item 4): the penalty law, the workpiece's [contact] table, the
Reis plant deflecting under a pressing command (lockstep), the F/T twin reading the contact."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from droid.cli import BadInput
from droid.experiments.geometry import trial_geometry
from droid.kinematics.transforms import inv_homo, trans
from droid.sim.contact import ContactParams, ToolContact, contact_force, surface_contact
from droid.sim.ft.lockstep import LockstepFt
from droid.sim.ft.netft import SENSOR_MODELS, wrench_on_sensor
from droid.sim.lockstep import Scheduler
from droid.sim.reis.cell import LockstepArm
from droid.sim.reis.plant import ReisPlant, ReisPlantParams
from droid.sim.workpiece import load_workpiece
from droid.tasks.seam.layout import T_W_SEAM

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
    path = tmp_path / "w.toml"
    path.write_text(f'[[segment]]\ntype = "line"\nlength_mm = 50\n[contact]\n{table}\n')
    with pytest.raises(BadInput) as exc:
        load_workpiece(str(path))
    assert "\n" not in str(exc.value) and message in str(exc.value), str(exc.value)


def test_contact_on_a_3d_workpiece_is_refused(tmp_path):
    path = tmp_path / "w.toml"
    path.write_text('[[segment]]\ntype = "line"\nlength_mm = 50\nrise_mm = 5\n[contact]\n')
    with pytest.raises(BadInput, match="plane workpieces only"):
        load_workpiece(str(path))


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
    q0 = geo.reis.ik(wcp_for(3.0), np.zeros(6))
    cmd = arm.command_joint(np.rint(geo.reis.gearing.joints_to_counts(q0)).astype(np.int32), arm.ticks_for(4.0))
    assert arm.move_done(cmd, 9.0)
    contact = ToolContact(geo.workpiece, geo.T_global_W, geo.reis.base, T_tool)
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
    from droid.brain.cellfile import load_cell

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
