"""The Reis arm in droid-sim: its plant behind a shared-memory VME register map.

Device type ``reis_vme`` (cell file)::

    [world.devices.arm1]
    type = "reis_vme"
    subunit = "arm1"        # whose [subunits.arm1] vme URL, robot file and base pose to use (default: the device name)
    seed = 7                # power-up encoder values and joint positions (default: the world seed)
    robot = "reis_v15"      # optional: must name the subunit's robot file (a cell whose controller and
                            # world name different robot files for one arm is refused, with both names)
    # the world is not the model (issue 13) -- errors the controller does not know:
    home_error_deg = [0, 0.3, -0.2, 0.1, 0.4, 0]   # true switch minus the robot file's [deg], or
    calibration_seed = 3                            # random errors of documented size (below)
    link_error_mm = [0, 0.5, 0, -0.3, 0, 0]         # D-H d_i (d_mm, joints with d != 0) or a_i (a_mm) errors
    twist_error_deg = [0.02, 0, 0, 0, 0, 0]         # D-H alpha errors [deg]
    compliance = true                               # harmonic-drive compliance (default false: rigid)
    contact_workpiece = "step_input"                # the tool touches this workpiece (docs/contact.md) ...
    contact_workpiece_pose = [400, 300, 1000, 0, 0, 0]   # ... fixed here (global T W, mm, ZYZ deg)
    contact_tool_pose = [0, 0, 250, -90, 90, 180]   # T_wcp_tool (default: the seam layout's tool point)

``calibration_seed = N`` draws, seeded: home-switch errors uniform in +-0.5 deg
on joints 2-5 (joints 1 and 6 are arbitrary by definition, thesis §4.1.1.4:
their zeros are set by the workspace centre and an inclinometer) and 0 on 1
and 6; length errors uniform +-0.5 mm on the non-zero D-H lengths; twist errors
uniform +-0.02 deg (machining tolerances of a welded/cast arm).  Explicit keys
override the drawn values.

``link_error_mm`` entry i changes the non-zero one of d_i and a_i of the D-H table
(Table 4.1: d1, a2, d4).

droid-servo and droid-watchdog open the same bytes with ``open_vme(url)``.
The device also implements the arm-twin interface of the world:
``wcp_global()`` -- the true wrist-centre pose [mm] in the global frame, used
by the camera twin -- and publishes its truth through the world's door
(:mod:`droid.sim.truth`; ``droid-sim truth ARM --json``).
"""
from __future__ import annotations

import sys

import numpy as np

from droid.cli import BadInput
from droid.kinematics import RobotFileError, load_robot
from droid.kinematics.transforms import pose_to_T
from droid.arm.rigid_body import DhError, world_backend
from droid.sim.reis.plant import ReisPlant, ReisPlantParams
from droid.sim.truth import TRUTH_PERIOD_S, TruthDoor, door_name
from droid.sim.reis.vme_shm import SharedVmeMap
from droid.sim.device import Device
from droid.subunits.reis.device import SERVO_HZ
from droid.subunits.reis.endpoints import reis_endpoints

HOME_ERROR_MAX_DEG = 0.5  # calibration_seed: home-switch errors, joints 2-5
LINK_ERROR_MAX_MM = 0.5  # calibration_seed: D-H length errors
TWIST_ERROR_MAX_DEG = 0.02  # calibration_seed: D-H twist errors
_CONTACT_OPTIONS = {"contact_workpiece", "contact_workpiece_pose", "contact_tool_pose"}
_OPTIONS = {"subunit", "seed", "robot", "home_error_deg", "calibration_seed", "link_error_mm", "twist_error_deg",
            "compliance"} | _CONTACT_OPTIONS
#: T_wcp_tool when ``contact_tool_pose`` is not given: the seam layout's tool point (a 100 mm
#: flange + the fixture's 150 mm, droid/cells/seamtrack_layout.toml) = sim.toml's F/T twin's
DEFAULT_CONTACT_TOOL_POSE = [0.0, 0.0, 250.0, -90.0, 90.0, 180.0]


class ReisDevice(Device):
    """The Reis arm twin: its plant stepped at every 1 ms world step (``step_s`` 0); the world
    need wake for it only at droid-servo's rate (``wake_hz``: the servo reads the encoders and
    writes the DACs at 500 Hz, the watchdog reads at 50 Hz), taking the two 1 ms plant steps
    of a 2 ms wake-up back to back, as lockstep steps the plant once per servo tick
    (docs/architecture.md "The world's rates")."""
    wake_hz = float(SERVO_HZ)

    def __init__(self, name: str, shared: SharedVmeMap, plant: ReisPlant, model, door: TruthDoor | None = None) -> None:
        self.name = name
        self.shared = shared
        self.plant = plant
        self.model = model
        self.door = door
        self._latch_told = False
        self._wcp_q: bytes | None = None  # the true joint angles of the cached wrist-centre pose (their bytes)
        self._wcp = None
        self._truth_due_s = 0.0  # world time of the next truth-door write [s]

    def advance(self, dt_s: float) -> None:
        self.plant.advance(dt_s)
        if self.plant._wd_fault and not self._latch_told:  # say why the amplifiers went off (issue 16)
            self._latch_told = True
            print(f"droid-sim: {self.name}: watchdog timers expired at world time {self.plant.time_s:.3f} s "
                  f"(registers unchanged for {1e3 * max(self.plant._wd_age_s):.0f} ms > "
                  f"{1e3 * self.plant.params.watchdog_timeout_s:.0f} ms): amplifiers latched off",
                  file=sys.stderr, flush=True)
        if self.door is not None and self.plant.time_s >= self._truth_due_s - 1e-9:
            self._truth_due_s = self.plant.time_s + TRUTH_PERIOD_S
            self.door.write(self.plant.time_s, self.plant.joint_deg, self.wcp_global()[:3, 3])

    def wcp_global(self) -> np.ndarray:
        """The true wrist-centre pose (4x4, mm, global frame): the true arm at its true angles.

        Computed when the true joint angles change (bit for bit: the pose is a function of them
        alone) and shared by every device that asks meanwhile (the truth door, the F/T twin, the
        sensor twins on this arm): an arm at rest costs no forward kinematics.  Callers must
        not modify it."""
        q = self.plant.joint_deg.tobytes()
        if self._wcp_q != q:
            self._wcp, self._wcp_q = self.model.base @ self.plant.wcp_true(), q
        return self._wcp

    def contact_wrench_N_Nm(self) -> tuple[np.ndarray, np.ndarray]:
        """The environment's wrench on the tool (global frame; force [N], torque [N m] about the
        tool point; docs/ft.md): the plant's contact (droid.sim.contact.ToolContact), zero without."""
        c = getattr(self.plant, "contact", None)
        return c.contact_wrench_N_Nm() if c is not None else (np.zeros(3), np.zeros(3))

    def close(self) -> None:
        close = getattr(self.plant, "close", None)
        if close is not None:
            close()
        if self.door is not None:
            self.door.close()
        self.shared.close()


def _six(where: str, key: str, value) -> tuple:
    if (not isinstance(value, list) or len(value) != 6
            or not all(isinstance(v, (int, float)) and not isinstance(v, bool) and np.isfinite(v) for v in value)):
        raise BadInput(f"{where} {key}: expected a list of 6 numbers")
    return tuple(float(v) for v in value)


def world_errors(where: str, model, options: dict) -> tuple[tuple, DhError]:
    """(home_error_deg, DhError) from a device table (see the module docstring)."""
    home = [0.0] * 6
    length = [0.0] * 6
    twist = [0.0] * 6
    if "calibration_seed" in options:
        seed = options["calibration_seed"]
        if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
            raise BadInput(f"{where} calibration_seed: expected an integer >= 0")
        rng = np.random.default_rng(seed)
        home = [0.0] + list(rng.uniform(-HOME_ERROR_MAX_DEG, HOME_ERROR_MAX_DEG, 4)) + [0.0]
        length = list(rng.uniform(-LINK_ERROR_MAX_MM, LINK_ERROR_MAX_MM, 6))
        twist = list(rng.uniform(-TWIST_ERROR_MAX_DEG, TWIST_ERROR_MAX_DEG, 6))
    if "home_error_deg" in options:
        home = list(_six(where, "home_error_deg", options["home_error_deg"]))
        if max(abs(v) for v in home) > 5.0:
            raise BadInput(f"{where} home_error_deg: errors above 5 deg are not calibration errors")
    if "link_error_mm" in options:
        length = list(_six(where, "link_error_mm", options["link_error_mm"]))
        if max(abs(v) for v in length) > 10.0:
            raise BadInput(f"{where} link_error_mm: errors above 10 mm are not calibration errors")
    if "twist_error_deg" in options:
        twist = list(_six(where, "twist_error_deg", options["twist_error_deg"]))
        if max(abs(v) for v in twist) > 1.0:
            raise BadInput(f"{where} twist_error_deg: errors above 1 deg are not calibration errors")
    dh = model.dh
    d_err = [e if dh is not None and dh.d_mm[i] != 0 else 0.0 for i, e in enumerate(length)]
    a_err = [e if dh is not None and dh.d_mm[i] == 0 and dh.a_mm[i] != 0 else 0.0 for i, e in enumerate(length)]
    return tuple(home), DhError(d_mm=tuple(d_err), a_mm=tuple(a_err), alpha_deg=tuple(twist))


def contact_from_options(where: str, options: dict, T_global_base):
    """The tool's contact with a workpiece (droid.sim.contact.ToolContact) from a device table,
    or None without ``contact_workpiece``::

        contact_workpiece = "step_input"                  # a workpiece with a [contact] table
        contact_workpiece_pose = [x, y, z, A, B, C]       # global T W (mm, ZYZ deg): where it is fixed
        contact_tool_pose = [0, 0, 250, -90, 90, 180]     # T_wcp_tool (default: the seam layout's tool point)
    """
    if "contact_workpiece" not in options:
        extra = sorted(set(options) & _CONTACT_OPTIONS)
        if extra:
            raise BadInput(f"{where} {extra[0]}: needs contact_workpiece")
        return None
    from droid.sim.contact import ToolContact
    from droid.sim.workpiece import load_workpiece

    name = options["contact_workpiece"]
    if not isinstance(name, str) or not name:
        raise BadInput(f"{where} contact_workpiece: expected a workpiece name or path")
    wp = load_workpiece(name)
    if wp.contact is None:
        raise BadInput(f"{where} contact_workpiece: workpiece {wp.name} has no [contact] table (docs/contact.md)")
    if "contact_workpiece_pose" not in options:
        raise BadInput(f"{where} contact_workpiece: needs contact_workpiece_pose (where the workpiece is fixed)")
    T_W = pose_to_T(*_six(where, "contact_workpiece_pose", options["contact_workpiece_pose"]))
    T_tool = pose_to_T(*_six(where, "contact_tool_pose", options.get("contact_tool_pose", DEFAULT_CONTACT_TOOL_POSE)))
    return ToolContact(wp, T_W, T_global_base, T_tool)


def device_subunit(cell, name: str, options: dict):
    """``(where, subunit)`` of a Reis world device's table, checked: no unknown key, and the
    world's robot file (if named) is the controller's -- one arm, one robot file."""
    where = f"{cell.path}: [world.devices.{name}]"
    unknown = set(options) - _OPTIONS
    if unknown:
        raise BadInput(f"{where}: unknown key(s) {', '.join(sorted(unknown))}")
    sub = cell.subunit(options.get("subunit", name))
    if "robot" in options and options["robot"] != sub.robot:
        raise BadInput(f"{where}: the world's robot file {options['robot']!r} differs from the controller's "
                       f"{sub.robot!r} ([subunits.{sub.name}] robot): one arm, one robot file")
    return where, sub


def make_reis(world, name: str, options: dict) -> ReisDevice:
    cell = world.cell
    where, sub = device_subunit(cell, name, options)
    url = reis_endpoints(cell, sub).vme
    if not url.startswith("shm://"):
        raise BadInput(f"{where} the simulated VME map needs a shm:// URL, got {url!r}")
    seed = int(options.get("seed", world.seed))
    try:
        model = load_robot(sub.robot).with_base(pose_to_T(*sub.base))
    except RobotFileError as exc:
        raise BadInput(str(exc)) from None
    if model.dynamics is None or model.dh is None:
        raise BadInput(f"{model.source}: [dynamics] and [dh] are needed to simulate the arm")
    home_error, dh_error = world_errors(where, model, options)
    contact = contact_from_options(where, options, model.base)
    # Rigid drives unless the cell asks for compliance = true: with the harmonic drives'
    # compliance (the robot file's stiffness; lockstep --arm full uses it) the real-time
    # servo hunts at standstill and a loaded host's cell failed its stop tests (issue 13, open).
    compliance = options.get("compliance", False)
    if not isinstance(compliance, bool):
        raise BadInput(f"{where} compliance: must be true or false, got {compliance!r}")
    params = ReisPlantParams(robot=sub.robot, home_error_deg=home_error, dh_error=dh_error, compliance=compliance)
    shared = SharedVmeMap.create(url[len("shm://"):], replace=True)
    door = None
    try:
        plant = ReisPlant(params, seed, regs=shared.buf, rigid_body=world_backend())  # no Pinocchio import
        plant.contact = contact
        door = TruthDoor.create(door_name(cell.name, sub.name))
    except BaseException:
        shared.close()
        raise
    return ReisDevice(name, shared, plant, model, door)
