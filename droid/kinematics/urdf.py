"""A robot file as URDF: links, revolute joints, limits, masses and inertias, geometry (issue 29).

:func:`robot_urdf` turns a :class:`~droid.kinematics.model.RobotModel` into the text of a
URDF (ROS's Unified Robot Description Format) that other tools -- Pinocchio, yourdfpy,
RViz, Foxglove, MoveIt -- read.  It is a pure function of the model (no I/O); the shell
is ``droid-kin urdf`` (:mod:`droid.kinematics.cli`), and every bundled robot's URDF is
generated from its file into ``droid/kinematics/robots/urdf/<robot>.urdf``
(``droid-kin urdf --write-bundled``; a test regenerates them byte for byte).

Joint zero and signs are DROID's: a joint vector ``q`` [rad] in the URDF gives the same
``tool0`` pose as ``droid-kin fk`` (``RobotModel.fk``) of ``degrees(q)``: the joint
variables are the robot's own (for the bundled robots the D-H joint variables of thesis
Table 4.1), the OPW offsets and sign corrections are built into the joint origins and
axes.  The chain is the OPW model (Brandstötter 2014; :mod:`droid.kinematics.opw`)::

    Rz(t1) T(a1, b, c1) Ry(t2) T(0, 0, c2) Ry(t3) T(a2, 0, c3/2) Rz(t4) T(0, 0, c3/2)
    Ry(t5) Rz(t6) T(0, 0, c4),        t_i = sign_i q_i - offset_i

written ROS-Industrial style: at q = 0 every link frame is parallel to ``base_link``
(each joint's ``origin`` is a pure translation, its ``axis`` a signed unit vector), which
describes the same motion (product of exponentials).

Frames (ROS-Industrial names):

* ``base_link`` -- the robot frame of docs/kinematics.md §1 (origin on the joint-1 axis at
  the floor of the base, z up): the model's ``base`` (its pose in a cell) is *not* in the
  URDF; a viewer places ``base_link`` with the cell's ``base``.
* ``link_1`` .. ``link_6`` -- the bodies moved by joints ``joint_1`` .. ``joint_6``; origin
  on the joint axis, axes parallel to ``base_link`` at q = 0.  Joint 4's origin is half way
  along the forearm (any point on its axis gives the same kinematics).
* ``flange`` -- where the wrist ends: ``c4`` along the last axis from the wrist centre
  (c4 = 0 for every bundled robot, so it is the wrist centre), x out of the wrist
  (ROS-Industrial's flange convention).
* ``tool0`` -- exactly the frame ``droid-kin fk`` reports: the wrist-centre point (WCP)
  frame of the thesis (§4.1.1, eq. 4.2) displaced by c4; z out of the wrist, same origin
  as ``flange`` (``flange -> tool0`` is Ry(+90 deg)).
* ``tool`` and ``sensor`` (optional) -- fixed to ``tool0`` by ``T_wcp_tool`` /
  ``T_wcp_sensor`` (a cell's world-device mounts, ``tool_pose`` / ``sensor_pose``).  They
  carry no mass: the robot files' link 6 already includes the payload.

Masses and inertias come from the file's ``[dynamics]`` (link *i*'s centre of mass and
inertia about it are given in D-H frame *i*, so a file with ``[dynamics]`` needs ``[dh]``);
each is written about the centre of mass in the link frame's axes (``rpy="0 0 0"``).  A file
without ``[dynamics]`` gives a kinematic URDF (no ``<inertial>``, ``effort="0"``).  Joint
limits: ``[limits]`` joint range and ``vmax_deg_s`` in rad and rad/s; effort [N m] is the
joint torque of the joint's motor at its amplifier's current limit through its reduction,
``k_t * I_max * N`` (coupling ignored).  Geometry (visual = collision) is nominal: a
capsule (cylinder + two spheres) per link between successive joint origins, radius
``LINK_RADIUS_FRACTION`` of the arm's reach (``WRIST_RADIUS_FRACTION`` for links 4-6) or the
file's ``[geometry] link_radius_mm``, a disc for the base (twice link 1's radius), a rod to
the tool and a box for the sensor; a link the file's ``[geometry] visual_mesh`` /
``collision_mesh`` names gets that mesh instead (in the link's URDF frame, metres, the
name written as given).  Units in the URDF are SI
(m, rad, kg, kg m^2, N m, rad/s).
"""
from __future__ import annotations

import math
from xml.sax.saxutils import quoteattr

import numpy as np

from .dh import link_matrix
from .dynamics import check_inertia
from .robots import BUNDLED_DIR, RobotFileError
from .transforms import inv_homo, is_rigid

#: capsule radius of links 1-3 and the base disc's radius / 2, as a fraction of the reach.
LINK_RADIUS_FRACTION = 0.06
#: capsule radius of links 4-6 as a fraction of the reach.
WRIST_RADIUS_FRACTION = 0.035
#: base disc thickness as a fraction of c1 (shoulder height).
BASE_HEIGHT_FRACTION = 0.08
#: tool rod radius [m] and sensor box size [m].
TOOL_RADIUS_M = 0.012
SENSOR_BOX_M = (0.08, 0.06, 0.05)
#: where joint 4's origin sits along the forearm (0: at the elbow, 1: at the wrist centre).
JOINT4_ALONG_FOREARM = 0.5
#: where the bundled robots' generated URDFs live (``droid-kin urdf --write-bundled``).
BUNDLED_URDF_DIR = BUNDLED_DIR / "urdf"
#: numbers closer than this to 0 are written as 0 (cos 90 deg is 6e-17, not 0).
_SNAP = 1e-12

_MM = 1e-3  # m per mm

_X, _Y, _Z = np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0]), np.array([0.0, 0.0, 1.0])
#: joint axes of the OPW chain in each joint's own frame
_OPW_AXES = (_Z, _Y, _Y, _Z, _Y, _Z)


def _rot(axis: np.ndarray, angle_rad: float) -> np.ndarray:
    """4x4 rotation about a unit axis (Rodrigues)."""
    x, y, z = axis
    c, s = math.cos(angle_rad), math.sin(angle_rad)
    k = np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])
    t = np.eye(4)
    t[:3, :3] = np.eye(3) + s * k + (1.0 - c) * (k @ k)
    return t


def _tr(x: float, y: float, z: float) -> np.ndarray:
    t = np.eye(4)
    t[:3, 3] = (x, y, z)
    return t


def bundled_urdf_path(name: str):
    """Path of a bundled robot's generated URDF (``droid/kinematics/robots/urdf/<name>.urdf``)."""
    return BUNDLED_URDF_DIR / f"{name}.urdf"


def opw_chain_frames(model) -> tuple[list[np.ndarray], list[np.ndarray], np.ndarray]:
    """The OPW chain at DROID's zero (q = 0) in the robot frame [mm].

    Returns (joint frames G_1..G_6 (4x4), joint axes in the robot frame (signed by the
    joint's sign correction: a positive q turns about it), the fk frame (4x4)).
    """
    p = model.opw
    lam = JOINT4_ALONG_FOREARM
    fixed = [  # translation before joint i (in joint i-1's rotated frame)
        np.eye(4),
        _tr(p.a1, p.b, p.c1),
        _tr(0.0, 0.0, p.c2),
        _tr(p.a2, 0.0, p.c3 * lam),
        _tr(0.0, 0.0, p.c3 * (1.0 - lam)),
        np.eye(4),
    ]
    t = np.eye(4)
    frames, axes = [], []
    for i in range(6):
        t = t @ fixed[i]
        # at q = 0 the OPW angle is -offset: G_i = (frame before joint i) Rot(axis_i, -offset_i)
        g = t @ _rot(_OPW_AXES[i], -math.radians(p.offsets_deg[i]))
        frames.append(g)
        axes.append(g[:3, :3] @ (_OPW_AXES[i] * p.signs[i]))
        t = g
    tip = t @ _tr(0.0, 0.0, p.c4)
    return frames, axes, tip


def default_link_radii_mm(model) -> tuple[float, float]:
    """The nominal capsule radii [mm] of links 1-3 and of links 4-6: fractions of the reach."""
    p = model.opw
    reach = p.c2 + math.hypot(p.a2, p.c3)
    return LINK_RADIUS_FRACTION * reach, WRIST_RADIUS_FRACTION * reach


def link_capsule_radii_mm(model) -> list[float]:
    """Radius [mm] of each of the six link capsules of the URDF (the file's ``[geometry]
    link_radius_mm`` where given, else :func:`default_link_radii_mm`).  The collision guard
    (:mod:`droid.guard.bodies`) sizes its bodies with this, so its capsules are the URDF's."""
    r_arm, r_wrist = default_link_radii_mm(model)
    given = model.geometry.link_radius_mm
    return [float(given[i]) if given is not None else (r_arm if i < 3 else r_wrist) for i in range(6)]


def _check_dynamics(model) -> None:
    dyn = model.dynamics
    if dyn is None:
        return
    if model.dh is None:
        raise RobotFileError(f"{model.name}: [dh]: missing; [dynamics] link_com_mm and link_inertia_kgm2 are given "
                             "in D-H frames, so a URDF with masses needs the file's [dh] table")
    for i in range(6):
        m = float(dyn.link_mass_kg[i])
        if not (math.isfinite(m) and m > 0.0):
            raise RobotFileError(f"{model.name}: [dynamics] link_mass_kg: link {i + 1}: must be > 0 kg, got {m!r}")
        if not np.all(np.isfinite(dyn.link_com_mm[i])):
            raise RobotFileError(f"{model.name}: [dynamics] link_com_mm: link {i + 1}: must be finite")
        inertia = np.asarray(dyn.link_inertia_kgm2[i], float)
        if inertia.shape != (3, 3) or not np.all(np.isfinite(inertia)) or not np.allclose(inertia, inertia.T):
            raise RobotFileError(f"{model.name}: [dynamics] link_inertia_kgm2: link {i + 1}: "
                                 "must be a finite symmetric 3x3 inertia")
        try:
            check_inertia(i, inertia)
        except ValueError as exc:
            raise RobotFileError(f"{model.name}: {exc}") from None


def _f(v: float) -> str:
    v = float(v)
    if abs(v) < _SNAP:
        v = 0.0
    text = f"{v:.12g}"
    return "0" if text == "-0" else text


def _vec(v) -> str:
    return " ".join(_f(x) for x in v)


def _rpy(R: np.ndarray) -> tuple[float, float, float]:
    """URDF roll-pitch-yaw (R = Rz(yaw) Ry(pitch) Rx(roll)) of a rotation matrix [rad]."""
    r = np.where(np.abs(R) < _SNAP, 0.0, R)
    pitch = math.atan2(-r[2, 0], math.hypot(r[0, 0], r[1, 0]))
    if math.hypot(r[0, 0], r[1, 0]) < 1e-9:  # gimbal lock: yaw 0, R = Ry(pitch) Rx(roll)
        yaw = 0.0
        roll = math.atan2(-r[1, 2], r[1, 1])
    else:
        yaw = math.atan2(r[1, 0], r[0, 0])
        roll = math.atan2(r[2, 1], r[2, 2])
    return roll, pitch, yaw


def _origin(T_mm: np.ndarray) -> str:
    """``<origin>`` of a 4x4 transform [mm] (xyz in m)."""
    xyz = _vec(T_mm[:3, 3] * _MM)
    rpy = _vec(_rpy(T_mm[:3, :3]))
    return f'<origin xyz="{xyz}" rpy="{rpy}"/>'


def _capsule(a_m: np.ndarray, b_m: np.ndarray, radius_m: float) -> list[str]:
    """Geometry elements of a capsule from a to b [m] in the link frame: cylinder + end spheres."""
    out = []
    d = b_m - a_m
    length = float(np.linalg.norm(d))
    if length > 1e-9:
        z = d / length
        # rotation taking +z to the segment direction
        ref = _Y if abs(z[1]) < 0.9 else _Z  # a segment along +z gets the identity
        x = np.cross(ref, z)
        x /= np.linalg.norm(x)
        y = np.cross(z, x)
        T = np.eye(4)
        T[:3, :3] = np.column_stack([x, y, z])
        T[:3, 3] = (a_m + b_m) / 2.0 / _MM
        out.append((_origin(T), f'<cylinder radius="{_f(radius_m)}" length="{_f(length)}"/>'))
    out.append((_origin(_tr(*(a_m / _MM))), f'<sphere radius="{_f(radius_m)}"/>'))
    if length > 1e-9:
        out.append((_origin(_tr(*(b_m / _MM))), f'<sphere radius="{_f(radius_m)}"/>'))
    return out


def _geometry_xml(visual: list, collision: list, indent: str, material: str = "droid_grey") -> list[str]:
    lines = []
    for tag, parts in (("visual", visual), ("collision", collision)):
        for origin, geom in parts:
            lines += [f"{indent}<{tag}>", f"{indent}  {origin}", f"{indent}  <geometry>{geom}</geometry>"]
            if tag == "visual":
                lines.append(f'{indent}  <material name="{material}"/>')
            lines.append(f"{indent}</{tag}>")
    return lines


def _link_geometry(model, k: int, capsule: list, indent: str) -> list[str]:
    """Visual and collision of link k (0: base_link, i: link_i): the file's meshes, else the capsule."""
    g = model.geometry
    out = []
    for meshes in (g.visual_mesh, g.collision_mesh):
        name = meshes[k] if meshes is not None else ""
        out.append([('<origin xyz="0 0 0" rpy="0 0 0"/>', f"<mesh filename={quoteattr(name)}/>")] if name else capsule)
    return _geometry_xml(out[0], out[1], indent)


def _inertial_xml(mass: float, com_m: np.ndarray, inertia: np.ndarray, indent: str) -> list[str]:
    i = inertia
    return [
        f"{indent}<inertial>",
        f'{indent}  <origin xyz="{_vec(com_m)}" rpy="0 0 0"/>',
        f'{indent}  <mass value="{_f(mass)}"/>',
        f'{indent}  <inertia ixx="{_f(i[0, 0])}" ixy="{_f(i[0, 1])}" ixz="{_f(i[0, 2])}" '
        f'iyy="{_f(i[1, 1])}" iyz="{_f(i[1, 2])}" izz="{_f(i[2, 2])}"/>',
        f"{indent}</inertial>",
    ]


def _mount(name: str, T) -> np.ndarray:
    t = np.asarray(T, float)
    if not is_rigid(t, tol=1e-6):
        raise ValueError(f"{name}: must be a 4x4 rigid transform T_wcp_{name} [mm]")
    return t


def robot_urdf(model, *, tool=None, sensor=None) -> str:
    """The URDF text of a robot model (see the module docstring for frames, units and data).

    ``tool`` / ``sensor``: 4x4 transforms [mm] of the tool point / the sensor in the frame
    ``droid-kin fk`` reports (``T_wcp_tool`` / ``T_wcp_sensor``), added as fixed links
    ``tool`` / ``sensor`` on ``tool0``; None: no such link.

    Raises :class:`~droid.kinematics.robots.RobotFileError` (one line naming the key) when
    the file cannot make a valid URDF: ``[dynamics]`` without ``[dh]``, a mass that is not
    > 0, an inertia that is not positive definite (or not physical); ValueError for a
    ``tool``/``sensor`` that is not a rigid transform.
    """
    _check_dynamics(model)
    tool_T = None if tool is None else _mount("tool", tool)
    sensor_T = None if sensor is None else _mount("sensor", sensor)
    p = model.opw
    frames, axes, tip = opw_chain_frames(model)
    pos = [g[:3, 3].copy() for g in frames]  # joint origins at q = 0 [mm], robot frame
    r_arm, r_wrist = (r * _MM for r in default_link_radii_mm(model))

    L = _header_xml(model)
    # base_link: a disc under joint 1
    h = BASE_HEIGHT_FRACTION * p.c1 * _MM
    r_base = 2.0 * (r_arm if model.geometry.link_radius_mm is None else model.geometry.link_radius_mm[0] * _MM)
    L.append('  <link name="base_link">')
    base_geom = [(_origin(_tr(0.0, 0.0, h / 2.0 / _MM)), f'<cylinder radius="{_f(r_base)}" length="{_f(h)}"/>')]
    L += _link_geometry(model, 0, base_geom, "    ")
    L.append("  </link>")
    L += _arm_xml(model, pos, axes, tip[:3, 3], r_arm, r_wrist)
    L += _flange_xml(pos, tip)
    L += _mounts_xml(tool_T, sensor_T)
    L.append("</robot>")
    return "\n".join(L) + "\n"


def _header_xml(model) -> list[str]:
    """The XML declaration, the comment on where the file comes from, ``<robot>`` and its materials."""
    L: list[str] = []
    L.append('<?xml version="1.0"?>')
    L.append(f"<!-- {model.name}: generated by droid-kin urdf from the robot file (droid.kinematics.urdf);")
    L.append("     do not edit: regenerate it (docs/kinematics.md, URDF).")
    L.append("     Joint angles are DROID's (droid-kin fk, in rad): tool0 is the frame droid-kin fk reports")
    L.append("     (the wrist-centre point frame displaced by c4).  SI units.")
    if model.assumed:
        L.append("     The robot file's data are ASSUMED (see its comments and [dynamics.source]).")
    if model.dynamics is None:
        L.append("     The robot file has no [dynamics]: no masses or inertias, effort 0.")
    L.append("-->")
    L.append(f"<robot name={quoteattr(model.name)}>")
    L.append('  <material name="droid_grey"><color rgba="0.6 0.6 0.62 1"/></material>')
    L.append('  <material name="droid_orange"><color rgba="0.95 0.5 0.1 1"/></material>')
    return L


def _dh_frames(model) -> list[np.ndarray]:
    """The D-H frames at q = 0 (for the ``[dynamics]`` data); none without ``[dynamics]``."""
    dh_frames = []
    if model.dynamics is not None:
        t = np.eye(4)
        d = model.dh
        for i in range(6):
            t = t @ link_matrix(math.radians(d.theta_offset_deg[i]), d.d_mm[i], d.a_mm[i], math.radians(d.alpha_deg[i]))
            dh_frames.append(t.copy())
    return dh_frames


def _arm_xml(model, pos, axes, flange_pos, r_arm: float, r_wrist: float) -> list[str]:
    """joint_1 .. joint_6 (limits; effort from the amplifiers' current limit) and link_1 ..
    link_6 (inertials from ``[dynamics]``, capsules to the next joint)."""
    dyn = model.dynamics
    dh_frames = _dh_frames(model)
    L: list[str] = []
    for i in range(6):
        n = i + 1
        parent = "base_link" if i == 0 else f"link_{i}"
        prev = np.zeros(3) if i == 0 else pos[i - 1]
        L.append(f'  <joint name="joint_{n}" type="revolute">')
        L.append(f'    <parent link="{parent}"/>')
        L.append(f'    <child link="link_{n}"/>')
        L.append(f'    <origin xyz="{_vec((pos[i] - prev) * _MM)}" rpy="0 0 0"/>')
        L.append(f'    <axis xyz="{_vec(axes[i])}"/>')
        effort = 0.0
        if dyn is not None:
            effort = float(dyn.torque_constant_nm_per_a[i] * dyn.amp_current_limit_a[i] * model.gearing.reduction[i])
        L.append(f'    <limit lower="{_f(math.radians(model.joint_min_deg[i]))}" '
                 f'upper="{_f(math.radians(model.joint_max_deg[i]))}" '
                 f'velocity="{_f(math.radians(model.vmax_deg_s[i]))}" effort="{_f(effort)}"/>')
        L.append("  </joint>")
        L.append(f'  <link name="link_{n}">')
        if dyn is not None:
            D = dh_frames[i]
            R = D[:3, :3]
            com = (R @ np.asarray(dyn.link_com_mm[i], float) + D[:3, 3] - pos[i]) * _MM
            inertia = R @ np.asarray(dyn.link_inertia_kgm2[i], float) @ R.T
            inertia = (inertia + inertia.T) / 2.0
            L += _inertial_xml(float(dyn.link_mass_kg[i]), com, inertia, "    ")
        end = pos[i + 1] if i < 5 else flange_pos
        radius = link_capsule_radii_mm(model)[i] * _MM
        L += _link_geometry(model, i + 1, _capsule(np.zeros(3), (end - pos[i]) * _MM, radius), "    ")
        L.append("  </link>")
    return L


def _flange_xml(pos, tip) -> list[str]:
    """The flange (x out of the wrist) and tool0 (the fk frame, z out of the wrist)."""
    ry90 = _rot(_Y, math.pi / 2.0)
    ry90[np.abs(ry90) < _SNAP] = 0.0
    flange_in_link6 = _tr(*(-pos[5])) @ tip @ inv_homo(ry90)
    L: list[str] = []
    L.append('  <joint name="joint_6-flange" type="fixed">')
    L.append('    <parent link="link_6"/>')
    L.append('    <child link="flange"/>')
    L.append(f"    {_origin(flange_in_link6)}")
    L.append("  </joint>")
    L.append('  <link name="flange"/>')
    L.append('  <joint name="flange-tool0" type="fixed">')
    L.append('    <parent link="flange"/>')
    L.append('    <child link="tool0"/>')
    L.append(f"    {_origin(ry90)}")
    L.append("  </joint>")
    L.append('  <link name="tool0"/>')
    return L


def _mounts_xml(tool_T, sensor_T) -> list[str]:
    """The fixed ``tool`` (a rod from the wrist centre) and ``sensor`` (a box) links on tool0."""
    L: list[str] = []
    for name, T in (("tool", tool_T), ("sensor", sensor_T)):
        if T is None:
            continue
        L.append(f'  <joint name="tool0-{name}" type="fixed">')
        L.append('    <parent link="tool0"/>')
        L.append(f'    <child link="{name}"/>')
        L.append(f"    {_origin(T)}")
        L.append("  </joint>")
        L.append(f'  <link name="{name}">')
        if name == "tool":
            # a rod from the wrist centre (tool0's origin, seen from the tool frame) to the tool point
            start = inv_homo(T)[:3, 3] * _MM
            parts = _capsule(start, np.zeros(3), TOOL_RADIUS_M)
        else:
            parts = [(_origin(np.eye(4)), f'<box size="{_vec(SENSOR_BOX_M)}"/>')]
        L += _geometry_xml(parts, parts, "    ", "droid_orange")
        L.append("  </link>")
    return L
