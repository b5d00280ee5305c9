"""The world's contact device (issue 27 item 4): a workpiece on the holder's wrist pushing on
the Reis tool, in droid-sim's world built from the cell file (no processes: the world in
this process, its shared memory closed by world.close())."""
from __future__ import annotations

import itertools

import numpy as np
import pytest

from droid.brain.cell.cellfile import load_cell
from droid.cli import BadInput
from droid.kinematics.transforms import inv_homo, pose_to_T, trans
from droid.sim.contact import ToolContact
from droid.sim.contact_device import ContactDevice
from droid.sim.reis.plant import ReisPlant, ReisPlantParams
from droid.sim.workpiece import load_workpiece
from droid.sim.world import build_world
from tests.brain.cellutil import make_cell_file

MOUNT = pose_to_T(50.0, -350.0, 150.0, 0.0, 90.0, 90.0)


def _world(tmp_path, cell_name, edit=None):
    path = make_cell_file(tmp_path, cell_name)
    cell = load_cell(path)
    # a live cell on this host may hold the shipped F/T ports: serve this one on free ones
    cell.world["devices"]["ft_sensor"]["device"] = "netft://127.0.0.1:0?http_port=0"
    if edit is not None:
        edit(cell.world["devices"])
    return build_world(cell)


def test_the_default_cell_puts_the_held_workpiece_under_the_reis_nozzle(tmp_path, cell_name):
    world = _world(tmp_path, cell_name)
    try:
        dev, arm, holder = world.devices["touch"], world.devices["arm1"], world.devices["gmf1_karel"]
        assert isinstance(dev, ContactDevice) and arm.plant.contact is dev.contact
        c = dev.contact
        assert c.workpiece.name == "step_input"
        # the surface rides on the holder's true wrist, as the sensors' workpiece does
        assert np.allclose(c.T_global_W, holder.wcp_global() @ MOUNT)
        assert np.allclose(world.devices["tool_sensor"].mount.T_global_workpiece(), c.T_global_W)
        assert np.allclose(c.T_wcp_tool[:3, 3], [0.0, 0.0, 235.0])  # the nozzle, 15 mm short of the tool point
        for _ in range(400):  # 0.4 s at power-up: the tool far above, nothing touches
            world.advance(0.001)
        assert not c.force_N.any() and dev.touches == 0 and c.depth_mm < -50.0
        # far from the surface the plant's steps are not asked (skip-while-far), but some are
        assert 1 <= c.evaluations < 100
        assert not arm.contact_wrench_N_Nm()[0].any()
    finally:
        world.close()
    assert arm.plant.contact is None  # closed: the contact let go of the plant


def test_a_held_workpiece_moves_its_surface_with_the_holder():
    """The same tool point, the holder's wrist moved 3 mm: pressed 1 mm, then 2 mm apart."""
    wp = load_workpiece("step_input")
    plant = ReisPlant(ReisPlantParams(), seed=4)
    T_tool = trans(0.0, 0.0, 250.0)
    probe = ToolContact(wp, np.eye(4), np.eye(4), T_tool)
    plant.contact = probe
    plant.advance(0.002)
    p = probe.tool_mm  # the tool point now (global, mm)
    holder = {"T": trans(p[0] - 30.0, p[1] + 25.0, p[2] + 1.0)}  # W under the point, its lower plate 1 mm above it
    held = ToolContact(wp, lambda: holder["T"], np.eye(4), T_tool)
    plant.contact = held
    plant.advance(0.002)
    assert held.depth_mm == pytest.approx(1.0, abs=0.05) and held.force_N[2] == pytest.approx(20.0, rel=0.1)
    holder["T"] = trans(p[0] - 30.0, p[1] + 25.0, p[2] - 2.0)
    plant.advance(0.002)
    assert held.depth_mm == pytest.approx(-2.0, abs=0.05) and not held.force_N.any()


def test_skipping_while_far_never_misses_a_touch():
    """A surface rising toward the tool at the bound's speed: the skipping contact touches in
    the same step as one asked every step, with the same force."""
    wp = load_workpiece("step_input")
    plants = [ReisPlant(ReisPlantParams(), seed=4) for _ in range(2)]
    T_tool = trans(0.0, 0.0, 250.0)
    plants[0].contact = ToolContact(wp, np.eye(4), np.eye(4), T_tool)
    plants[0].advance(0.002)
    p = plants[0].contact.tool_mm
    t = {"s": 0.0}
    v = 1000.0  # mm/s, the bound below

    def T_W():  # the lower plate starts 20 mm below the point and rises at v
        return trans(p[0] - 30.0, p[1] + 25.0, p[2] - 20.0 + v * t["s"])

    every = ToolContact(wp, T_W, np.eye(4), T_tool)
    skip = ToolContact(wp, T_W, np.eye(4), T_tool, max_closing_speed_mm_s=v)
    first = {}
    for k in range(20):
        t["s"] = k * 0.002
        for name, c in (("every", every), ("skip", skip)):
            tau = c.joint_torque(plants[1].body, plants[1]._q, plants[1]._qd, 0.002)
            if tau is not None and name not in first:
                first[name] = (k, c.force_N.copy())
    assert "every" in first and first["skip"][0] == first["every"][0]
    assert np.allclose(first["skip"][1], first["every"][1])
    assert skip.evaluations < every.evaluations


@pytest.mark.parametrize("edit, message", [
    (lambda d: d["touch"].update(workpiece="ramp_r200"), "has no [contact] table"),
    (lambda d: d["touch"].pop("holder_robot"), "is missing 'holder_robot'"),
    (lambda d: d["touch"].update(workpiece_pose=[0, 0, 0, 0, 0, 0]), "give either workpiece_pose"),
    (lambda d: d["touch"].update(tool_robot="mvs_camera"), "tool_robot"),
    (lambda d: d["touch"].update(holder_robot="nowhere"), "no device 'nowhere' declared before it"),
    (lambda d: d["touch"].update(max_closing_speed_mm_s=-1.0), "must be in (0, 1e6] mm/s"),
    (lambda d: d["touch"].update(touch_pose=[0, 0]), "touch_pose must be 6 finite numbers"),
    (lambda d: d["touch"].update(speed=3), "unknown key(s): speed"),
    (lambda d: d["arm1"].update(contact_workpiece="step_input", contact_workpiece_pose=[0, 0, 0, 0, 0, 0]),
     "already has a contact"),
])
def test_bad_contact_devices_are_one_line_and_nothing_is_left(tmp_path, cell_name, edit, message):
    with pytest.raises(BadInput) as exc:
        _world(tmp_path, cell_name, edit)
    assert "\n" not in str(exc.value) and message in str(exc.value), str(exc.value)
    assert "[world.devices.touch]" in str(exc.value) or "tool_robot" not in message


def test_a_plant_pressed_into_the_steps_wall_is_pushed_out_sideways():
    """The tool point 0.5 mm into the step's wall, 1 mm above the lower plate (2 mm step): the
    wall pushes it along -y_W (out of the wall, toward the lower plate), not up, and the
    tool, stepped by the plant, moves that way against a plant without contact."""
    wp = load_workpiece("step_input")
    T_tool = trans(0.0, 0.0, 250.0)
    free, pushed = (ReisPlant(ReisPlantParams(), seed=4) for _ in range(2))
    probe = ToolContact(wp, trans(0.0, 0.0, -5000.0), np.eye(4), T_tool)  # far away: never touches
    free.contact = probe
    free.advance(0.002)
    p = probe.tool_mm.copy()
    wall = ToolContact(wp, trans(p[0] - 30.0, p[1] - 0.5, p[2] - 1.0), np.eye(4), T_tool)  # p at (30, 0.5, 1) in W
    pushed.contact = wall
    pushed.advance(0.002)
    assert wall.depth_mm == pytest.approx(0.5) and np.allclose(wall.force_N, [0.0, -10.0, 0.0])
    for _ in range(15):
        free.advance(0.002)
        pushed.advance(0.002)
    moved = wall.tool_mm - probe.tool_mm
    assert moved[1] < -0.05 and abs(moved[2]) < 0.2 * abs(moved[1]), moved  # out of the wall, not up
    assert 0.0 < wall.depth_mm < 0.45  # still pressed, less deep
    f = wall.force_N
    assert f[1] < 0.0 and abs(f[2]) < 0.2 * abs(f[1]), f  # the wall's push (and its friction)


def _cad_curve_with_contact(tmp_path):
    import shutil

    from droid.sim.workpiece import WORKPIECE_DIR

    for f in WORKPIECE_DIR.glob("cad_curve*"):
        shutil.copy(f, tmp_path / f.name)
    path = tmp_path / "cad_curve.toml"
    path.write_text(path.read_text() + "\n[contact]\n")
    return load_workpiece(str(path))


def test_skipping_while_far_on_a_3d_workpiece_never_misses_a_touch(tmp_path):
    """cad_curve (rolled, curved) moving about the tool point at up to the bound's speed along
    a random path through its plates, beside them and far off: the skipping contact answers
    every step as the one asked every step does (the same torques, None alike)."""
    wp = _cad_curve_with_contact(tmp_path)
    assert not wp.planar
    seam = wp.seam
    plant = ReisPlant(ReisPlantParams(), seed=4)
    T_tool = trans(0.0, 0.0, 250.0)
    plant.contact = probe = ToolContact(wp, trans(0.0, 0.0, -5000.0), np.eye(4), T_tool)
    plant.advance(0.002)
    p = probe.tool_mm.copy()
    rng = np.random.default_rng(15)
    v, dt = 1000.0, 0.002  # the bound [mm/s], the plant's step [s]
    # waypoints of the tool point in W: on, in and under the plates, at the wall, beside, far above
    way = []
    for _ in range(14):
        q, _, n, l = seam.point_frame(rng.uniform(-30.0, seam.length_mm + 30.0))
        far = rng.random() < 0.3
        way.append(q + rng.uniform(-70.0, 70.0) * l + (rng.uniform(40.0, 150.0) if far else rng.uniform(-7.0, 3.0)) * n)
    path = [way[0]]
    for a, b in itertools.pairwise(way):
        k = max(1, int(np.ceil(np.linalg.norm(b - a) / (0.97 * v * dt))))
        path += [a + (b - a) * (j / k) for j in range(1, k + 1)]
    state = {"x": path[0]}

    def T_W():  # W placed so that the tool point is at x in W
        return trans(*(p - state["x"]))

    every = ToolContact(wp, T_W, np.eye(4), T_tool, max_depth_mm=5.0)
    skip = ToolContact(wp, T_W, np.eye(4), T_tool, max_closing_speed_mm_s=v, max_depth_mm=5.0)
    touched = 0
    for x in path:
        state["x"] = x
        a = every.joint_torque(plant.body, plant._q, plant._qd, dt)
        b = skip.joint_torque(plant.body, plant._q, plant._qd, dt)
        assert (a is None) == (b is None), x
        if a is not None:
            touched += 1
            assert np.array_equal(a, b) and np.array_equal(every.force_N, skip.force_N)
    assert touched > 20, touched
    assert skip.evaluations < 0.8 * every.evaluations, (skip.evaluations, every.evaluations)
