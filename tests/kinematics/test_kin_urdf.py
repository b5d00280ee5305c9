"""droid-kin urdf (issue 29 item 1): the URDF of a robot file, checked against independent tools.

Pinocchio (``buildModelFromXML``) and yourdfpy each read the URDF; their forward
kinematics of ``tool0`` must equal ``RobotModel.fk`` (what ``droid-kin fk`` prints) and
Pinocchio's mass matrix must equal the plant twin's.  The bundled robots' URDF files
must be exactly what the generator writes now.
"""
from __future__ import annotations

import dataclasses
import io
import math
import re
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest
import yourdfpy

from droid.kinematics import RobotFileError, list_robots, load_robot
from droid.kinematics.cli import main
from droid.kinematics.robots import BUNDLED_DIR
from droid.kinematics.transforms import pose_to_T
from droid.kinematics.urdf import BUNDLED_URDF_DIR, bundled_urdf_path, robot_urdf

from helpers_kin import offset_robot_toml

ROOT = Path(__file__).resolve().parents[2]
SIM_CELL = ROOT / "droid" / "cells" / "sim.toml"
#: tolerance of the FK comparison: position [mm], rotation matrix entries [1]
POS_TOL_MM = 1e-6
ROT_TOL = 1e-9
N_FK = 200
N_MASS = 20


def _dynamics_block() -> str:
    """The reis_v15 file's [dynamics] and [dynamics.source] tables, as text."""
    text = (BUNDLED_DIR / "reis_v15.toml").read_text()
    return text[text.index("\n[dynamics]\n"):]


@pytest.fixture(scope="module")
def offset_dyn_robot(tmp_path_factory):
    """The synthetic arm with every OPW offset non-zero (a1, a2, b, c4) and the Reis's [dynamics]."""
    path = tmp_path_factory.mktemp("urdf") / "offset_dyn.toml"
    path.write_text(offset_robot_toml("offset_dyn") + "\n" + _dynamics_block())
    return load_robot(str(path))


def _models(offset_robot, offset_dyn_robot):
    return [load_robot(n) for n in list_robots()] + [offset_robot, offset_dyn_robot]


def _pin(text: str) -> tuple[pin.Model, pin.Data]:
    model = pin.buildModelFromXML(text)
    return model, model.createData()


def _yourdf(text: str) -> yourdfpy.URDF:
    return yourdfpy.URDF.load(io.StringIO(text), build_scene_graph=True, load_meshes=False,
                              build_collision_scene_graph=False)


# ---------------------------------------------------------------- generated files


@pytest.mark.parametrize("name", list_robots())
def test_bundled_urdf_is_what_the_generator_writes(name):
    """Regenerating gives byte-identical files, so they cannot drift from the robot files."""
    path = bundled_urdf_path(name)
    assert path.is_file(), f"{path} missing: run droid-kin urdf --write-bundled"
    assert path.read_bytes() == robot_urdf(load_robot(name)).encode("utf-8"), \
        f"{path} is stale: run droid-kin urdf --write-bundled"


def test_every_bundled_robot_has_a_urdf_and_no_other():
    assert sorted(p.stem for p in BUNDLED_URDF_DIR.glob("*.urdf")) == list_robots()


def test_cli_prints_the_bundled_file(capsys):
    assert main(["urdf", "reis_v15"]) == 0
    assert capsys.readouterr().out == bundled_urdf_path("reis_v15").read_text()


def test_output_is_deterministic(offset_robot):
    assert robot_urdf(offset_robot) == robot_urdf(offset_robot)


# ---------------------------------------------------------------- structure


@pytest.mark.parametrize("name", list_robots())
def test_loads_in_pinocchio_and_yourdfpy_with_the_files_limits(name):
    m = load_robot(name)
    text = robot_urdf(m)
    pm, _ = _pin(text)
    assert pm.nq == 6 and pm.nv == 6
    assert [pm.names[i] for i in range(1, 7)] == [f"joint_{i}" for i in range(1, 7)]
    for f in ("base_link", "flange", "tool0"):
        assert pm.existFrame(f)
    assert np.allclose(pm.lowerPositionLimit, np.radians(m.joint_min_deg), atol=1e-11)
    assert np.allclose(pm.upperPositionLimit, np.radians(m.joint_max_deg), atol=1e-11)
    assert np.allclose(pm.velocityLimit, np.radians(m.vmax_deg_s), atol=1e-11)
    dyn = m.dynamics
    assert np.allclose(pm.effortLimit, dyn.torque_constant_nm_per_a * dyn.amp_current_limit_a * m.gearing.reduction)
    y = _yourdf(text)
    assert y.base_link == "base_link"
    assert y.actuated_joint_names == [f"joint_{i}" for i in range(1, 7)]
    assert {"link_1", "link_6", "flange", "tool0"} <= set(y.link_map)
    for i, jn in enumerate(y.actuated_joint_names):
        j = y.joint_map[jn]
        assert j.type == "revolute"
        assert j.limit.lower == pytest.approx(math.radians(m.joint_min_deg[i]), abs=1e-11)
        assert j.limit.upper == pytest.approx(math.radians(m.joint_max_deg[i]), abs=1e-11)
    # every link 1-6 carries the file's mass; visual and collision geometry on each
    for i in range(6):
        link = y.link_map[f"link_{i + 1}"]
        assert link.inertial.mass == pytest.approx(dyn.link_mass_kg[i])
        assert link.visuals and link.collisions
    assert sum(pm.inertias[i].mass for i in range(1, 7)) == pytest.approx(float(dyn.link_mass_kg.sum()))


def test_robot_without_dynamics_gives_a_kinematic_urdf(offset_robot):
    text = robot_urdf(offset_robot)
    assert "<inertial>" not in text and 'effort="0"' in text
    pm, _ = _pin(text)
    assert pm.nq == 6


# ---------------------------------------------------------------- forward kinematics


def _fk_errors(m, text: str, seed: int):
    """Largest |position| [mm] and |rotation entry| differences of tool0 vs RobotModel.fk."""
    pm, pd = _pin(text)
    fid = pm.getFrameId("tool0")
    y = _yourdf(text)
    rng = np.random.default_rng(seed)
    q_deg = rng.uniform(m.joint_min_deg, m.joint_max_deg, (N_FK, 6))
    worst = {"pin_mm": 0.0, "pin_rot": 0.0, "yourdfpy_mm": 0.0, "yourdfpy_rot": 0.0}
    for q in q_deg:
        T = m.fk(q)
        pin.framesForwardKinematics(pm, pd, np.radians(q))
        M = pd.oMf[fid]
        worst["pin_mm"] = max(worst["pin_mm"], float(np.max(np.abs(M.translation * 1000.0 - T[:3, 3]))))
        worst["pin_rot"] = max(worst["pin_rot"], float(np.max(np.abs(M.rotation - T[:3, :3]))))
        y.update_cfg(np.radians(q))
        Ty = y.get_transform("tool0", "base_link")
        worst["yourdfpy_mm"] = max(worst["yourdfpy_mm"], float(np.max(np.abs(Ty[:3, 3] * 1000.0 - T[:3, 3]))))
        worst["yourdfpy_rot"] = max(worst["yourdfpy_rot"], float(np.max(np.abs(Ty[:3, :3] - T[:3, :3]))))
    return worst


def test_tool0_fk_equals_droid_kin_fk(offset_robot, offset_dyn_robot):
    """200 seeded joint vectors per robot (inside its limits; the synthetic arm exercises
    a1, a2, b, c4 and every offset): Pinocchio's and yourdfpy's tool0 = droid-kin fk."""
    for k, m in enumerate(_models(offset_robot, offset_dyn_robot)):
        w = _fk_errors(m, robot_urdf(m), seed=100 + k)
        assert w["pin_mm"] < POS_TOL_MM and w["yourdfpy_mm"] < POS_TOL_MM, (m.name, w)
        assert w["pin_rot"] < ROT_TOL and w["yourdfpy_rot"] < ROT_TOL, (m.name, w)


def test_fk_check_can_fail(offset_robot):
    """The comparison notices a wrong sign correction: flip joint 2's axis in the text."""
    m = load_robot("reis_v15")
    text = robot_urdf(m)
    i = text.index('<joint name="joint_2"')
    j = text.index("</joint>", i)
    bad = text[:i] + text[i:j].replace('<axis xyz="0 -1 0"/>', '<axis xyz="0 1 0"/>') + text[j:]
    assert bad != text
    w = _fk_errors(m, bad, seed=1)
    assert w["pin_mm"] > 1.0 and w["yourdfpy_mm"] > 1.0


def test_flange_and_tool0_frames(offset_robot):
    """flange and tool0 share their origin (c4 beyond the wrist centre); flange x = tool0 z."""
    m = offset_robot
    pm, pd = _pin(robot_urdf(m))
    q = np.radians([10.0, -20.0, 30.0, 40.0, 50.0, 60.0])
    pin.framesForwardKinematics(pm, pd, q)
    fl, t0 = pd.oMf[pm.getFrameId("flange")], pd.oMf[pm.getFrameId("tool0")]
    assert np.allclose(fl.translation, t0.translation, atol=1e-12)
    assert np.allclose(fl.rotation[:, 0], t0.rotation[:, 2], atol=1e-12)
    # the wrist centre (joint 6's origin) lies c4 behind tool0 along its z
    wcp = pd.oMi[6].translation
    assert np.allclose(t0.translation - wcp, m.opw.c4 / 1000.0 * t0.rotation[:, 2], atol=1e-12)


# ---------------------------------------------------------------- dynamics


def test_mass_matrix_equals_the_plants(offset_dyn_robot):
    """Pinocchio's crba of the URDF = the plant twin's link-side mass matrix at 20 poses.

    The plant twins build their rigid body from the robot file's [dh] and [dynamics]
    (droid.arm.rigid_body.RigidBody, shared by the Reis plant and the GMF1 twin); on top
    of it they add the motors' reflected rotor inertias (GMF1: ``diag(J_r N^2)``; Reis: the
    rotor inertias through the coupled gearing), which a URDF cannot carry (no armature
    element).  So this compares the link-side part, ``RigidBody.mass(q)``, and the gravity
    torques (gravity set from the file, since URDF has none).
    """
    from droid.arm.rigid_body import RigidBody

    models = [load_robot(n) for n in list_robots()] + [offset_dyn_robot]
    for k, m in enumerate(models):
        pm, pd = _pin(robot_urdf(m))
        pm.gravity.linear = np.array([0.0, 0.0, -m.dynamics.gravity_mps2])
        pd = pm.createData()
        body = RigidBody(m.dh, m.dynamics)
        rng = np.random.default_rng(200 + k)
        for q in np.radians(rng.uniform(m.joint_min_deg, m.joint_max_deg, (N_MASS, 6))):
            M = pin.crba(pm, pd, q)
            M = np.triu(M) + np.triu(M, 1).T
            ref = body.mass(q)
            assert np.allclose(M, ref, rtol=1e-9, atol=1e-9), (m.name, np.max(np.abs(M - ref)))
            g = pin.computeGeneralizedGravity(pm, pd, q)
            assert np.allclose(g, body.gravity(q), rtol=1e-9, atol=1e-8), m.name


def test_mass_check_can_fail():
    """A link mass off by 1 kg in the URDF text changes the mass matrix beyond the tolerance."""
    from droid.arm.rigid_body import RigidBody

    m = load_robot("reis_v15")
    text = robot_urdf(m).replace('<mass value="25"/>', '<mass value="26"/>', 1)
    pm, pd = _pin(text)
    q = np.radians([0.0, 10.0, 20.0, 0.0, 30.0, 0.0])
    M = pin.crba(pm, pd, q)
    M = np.triu(M) + np.triu(M, 1).T
    assert not np.allclose(M, RigidBody(m.dh, m.dynamics).mass(q), rtol=1e-9, atol=1e-9)


# ---------------------------------------------------------------- cell mounts


def test_cell_tool_and_sensor_links(capsys, tmp_path):
    """--cell sim.toml --subunit arm1: tool and sensor fixed at the cell's T_wcp_tool / T_wcp_sensor."""
    out = tmp_path / "arm1.urdf"
    assert main(["urdf", "--cell", str(SIM_CELL), "--subunit", "arm1", "--out", str(out)]) == 0
    assert capsys.readouterr().out == ""
    text = out.read_text()
    m = load_robot("reis_v15")
    pm, pd = _pin(text)
    T_tool = pose_to_T(0.0, 0.0, 250.0, -90.0, 90.0, 180.0)  # droid/cells/sim.toml tool_pose
    T_sensor = pose_to_T(0.0, -100.0, 250.0, -90.0, 90.0, 180.0)  # sensor_pose
    rng = np.random.default_rng(7)
    for q in rng.uniform(m.joint_min_deg, m.joint_max_deg, (20, 6)):
        pin.framesForwardKinematics(pm, pd, np.radians(q))
        for frame, T_wcp in (("tool", T_tool), ("sensor", T_sensor)):
            want = m.fk(q) @ T_wcp
            got = pd.oMf[pm.getFrameId(frame)]
            assert np.allclose(got.translation * 1000.0, want[:3, 3], atol=POS_TOL_MM)
            assert np.allclose(got.rotation, want[:3, :3], atol=ROT_TOL)
    # the same with ROBOT given; the holder has no tool or sensor mounts
    assert main(["urdf", "reis_v15", "--cell", str(SIM_CELL), "--subunit", "arm1"]) == 0
    assert capsys.readouterr().out == text
    assert main(["urdf", "--cell", str(SIM_CELL), "--subunit", "gmf1"]) == 0
    assert capsys.readouterr().out == bundled_urdf_path("fanuc_s400").read_text()


# ---------------------------------------------------------------- bad input


def _bad_robot(tmp_path, name: str, edit) -> Path:
    path = tmp_path / f"{name}.toml"
    text = (BUNDLED_DIR / "reis_v15.toml").read_text()
    new = edit(text)
    assert new != text
    path.write_text(new.replace('name = "reis_v15"', f'name = "{name}"'))
    return path


def _one_line_exit_2(capsys, argv) -> str:
    assert main(argv) == 2
    cap = capsys.readouterr()
    assert cap.out == ""
    lines = cap.err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("droid-kin: "), cap.err
    return lines[0]


def test_refuses_missing_mass(capsys, tmp_path):
    path = _bad_robot(tmp_path, "no_mass", lambda t: re.sub(r"\nlink_mass_kg = \[[^\]]*\]", "", t, count=1))
    assert "link_mass_kg" in _one_line_exit_2(capsys, ["urdf", str(path)])


def test_refuses_inertia_not_positive_definite(capsys, tmp_path):
    path = _bad_robot(tmp_path, "bad_inertia",
                      lambda t: t.replace("[2.4,    1.2,    2.4,    0.0, 0.0, 0.0]", "[2.4, 1.2, 2.4, 3.0, 0.0, 0.0]"))
    line = _one_line_exit_2(capsys, ["urdf", str(path)])
    assert "link_inertia_kgm2" in line and "positive definite" in line


def test_refuses_dynamics_without_dh(capsys, tmp_path):
    def drop_dh(t):
        i = t.index("[dh]")
        return t[:i] + t[t.index("[opw]"):]

    path = _bad_robot(tmp_path, "no_dh", drop_dh)
    assert load_robot(str(path)).dh is None  # the robot file itself is fine for kinematics
    assert "[dh]" in _one_line_exit_2(capsys, ["urdf", str(path)])


def test_robot_urdf_refuses_a_model_built_around_the_loader():
    """The pure function checks too (a model made in code, not read from a file)."""
    m = load_robot("reis_v15")
    mass = m.dynamics.link_mass_kg.copy()
    mass[2] = 0.0
    bad = dataclasses.replace(m, dynamics=dataclasses.replace(m.dynamics, link_mass_kg=mass))
    with pytest.raises(RobotFileError, match="link_mass_kg: link 3"):
        robot_urdf(bad)
    inertia = m.dynamics.link_inertia_kgm2.copy()
    inertia[4] = np.diag([1.0, 1.0, -1.0])
    bad = dataclasses.replace(m, dynamics=dataclasses.replace(m.dynamics, link_inertia_kgm2=inertia))
    with pytest.raises(RobotFileError, match="link_inertia_kgm2: link 5"):
        robot_urdf(bad)
    with pytest.raises(ValueError, match="tool"):
        robot_urdf(m, tool=np.diag([1.0, 1.0, 2.0, 1.0]))


def test_out_into_missing_directory(capsys, tmp_path):
    line = _one_line_exit_2(capsys, ["urdf", "reis_v15", "--out", str(tmp_path / "nope" / "x.urdf")])
    assert "does not exist" in line
    assert not (tmp_path / "nope").exists()


@pytest.mark.parametrize("argv, words", [
    (["urdf"], "give ROBOT"),
    (["urdf", "no_such_robot"], "unknown robot"),
    (["urdf", "reis_v15", "--cell", str(SIM_CELL)], "together"),
    (["urdf", "--cell", str(SIM_CELL), "--subunit", "nobody"], "no subunit"),
    (["urdf", "fanuc_s400", "--cell", str(SIM_CELL), "--subunit", "arm1"], "carries"),
    (["urdf", "--cell", "/nonexistent/cell.toml", "--subunit", "arm1"], "not found"),
    (["urdf", "--write-bundled", "reis_v15"], "takes no"),
])
def test_bad_arguments(capsys, argv, words):
    assert words in _one_line_exit_2(capsys, argv)


def test_bad_cell_mount(capsys, tmp_path):
    cell = tmp_path / "cell.toml"
    cell.write_text(SIM_CELL.read_text().replace("tool_pose = [0.0, 0.0, 250.0, -90.0, 90.0, 180.0]",
                                                 "tool_pose = [0.0, 0.0, 250.0, -90.0, 90.0]"))
    line = _one_line_exit_2(capsys, ["urdf", "--cell", str(cell), "--subunit", "arm1"])
    assert "tool_pose" in line


def test_subprocess_exit_codes(tmp_path):
    """The console entry's exit codes: 0 with the URDF on stdout; 2 with one line for --out
    into a missing directory."""
    import os
    import subprocess
    import sys

    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    cmd = [sys.executable, "-m", "droid.kinematics.cli", "urdf", "reis_class_b"]
    r = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=60)
    assert r.returncode == 0 and r.stderr == ""
    assert r.stdout == bundled_urdf_path("reis_class_b").read_text()
    r = subprocess.run(cmd + ["--out", str(tmp_path / "missing" / "x.urdf")], capture_output=True, text=True,
                       env=env, timeout=60)
    assert r.returncode == 2 and r.stdout == ""
    assert len(r.stderr.strip().splitlines()) == 1 and "does not exist" in r.stderr


# ---------------------------------------------------------------- [geometry]

GEOMETRY = """
[geometry]
link_radius_mm = [90, 80, 70, 50, 40, 30]
visual_mesh = ["package://my_arm/meshes/base.stl", "", "link_2.dae", "", "", "", "file:///meshes/link_6.stl"]
collision_mesh = ["", "", "", "", "", "", "file:///meshes/link_6_hull.stl"]
"""


def test_geometry_table_names_meshes_and_radii(tmp_path):
    path = tmp_path / "meshy.toml"
    path.write_text(offset_robot_toml("meshy") + GEOMETRY)
    m = load_robot(str(path))
    text = robot_urdf(m)
    y = _yourdf(text)
    base, l2, l3, l6 = (y.link_map[n] for n in ("base_link", "link_2", "link_3", "link_6"))
    assert base.visuals[0].geometry.mesh.filename == "package://my_arm/meshes/base.stl"
    assert base.collisions[0].geometry.cylinder.radius == pytest.approx(0.18)  # twice link 1's
    assert l2.visuals[0].geometry.mesh.filename == "link_2.dae" and len(l2.visuals) == 1
    assert l2.collisions[0].geometry.cylinder.radius == pytest.approx(0.08)
    assert l3.visuals[0].geometry.cylinder.radius == pytest.approx(0.07)
    assert l6.visuals[0].geometry.mesh.filename == "file:///meshes/link_6.stl"
    assert l6.collisions[0].geometry.mesh.filename == "file:///meshes/link_6_hull.stl"
    # the kinematics do not change
    assert _fk_errors(m, text, seed=3)["pin_mm"] < POS_TOL_MM


@pytest.mark.parametrize("table, words", [
    ("[geometry]\nlink_radius_mm = [90, 80, 0, 50, 40, 30]\n", "link_radius_mm"),
    ("[geometry]\nvisual_mesh = [\"a.stl\"]\n", "visual_mesh"),
    ("[geometry]\ncollision_mesh = [\"\", \"\", \"\", \"\", \"\", \"\", \"x\\\"y.stl\"]\n", "collision_mesh"),
    ("[geometry]\nmesh = []\n", "unknown key"),
])
def test_bad_geometry_table(capsys, tmp_path, table, words):
    path = tmp_path / "bad_geometry.toml"
    path.write_text(offset_robot_toml("bad_geometry") + table)
    assert words in _one_line_exit_2(capsys, ["urdf", str(path)])


def test_write_bundled_writes_every_robot(capsys, tmp_path, monkeypatch):
    """--write-bundled writes one file per bundled robot, identical to the shipped ones."""
    import droid.kinematics.cli as cli

    monkeypatch.setattr(cli, "BUNDLED_URDF_DIR", tmp_path)
    monkeypatch.setattr(cli, "bundled_urdf_path", lambda name: tmp_path / f"{name}.urdf")
    assert main(["urdf", "--write-bundled"]) == 0
    assert capsys.readouterr().out.split() == [str(tmp_path / f"{n}.urdf") for n in list_robots()]
    for n in list_robots():
        assert (tmp_path / f"{n}.urdf").read_bytes() == bundled_urdf_path(n).read_bytes()
