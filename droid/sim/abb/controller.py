"""The ABB robot controller running EGM, in droid-sim (issue 26; docs/abb.md) -- core and device.

What the twin is: an IRC5/OmniCore executing droid/subunits/abb/rapid/DroidEGM.mod (EGMSetupUC,
EGMActJoint, EGMStreamStart, then EGMRunJoint in a loop), as far as the sensor side can see it:

* every ``period_s`` (4 ms, EGM's 250 Hz) of world time it sends an ``EgmRobot`` to the sensor
  address: header (``seqno`` +1 a message, ``tm`` its clock in ms, ``mtype`` DATA), feedback
  joints [deg] (the motor-side angles its resolvers measure) and time, its planned joints (the
  reference its joint loops follow), ``motorState``, ``rapidExecState``, ``mciState``,
  ``mciConvergenceMet`` and, if asked, ``testSignals`` (the reference's speed per joint [deg/s]);
  it streams while powered, guided or not (EGMStreamStart), as the RAPID module asks;
* ``EgmSensor`` joint targets [deg] it receives (clamped to the joint limits) are followed by
  the reference of its own joint loops, no faster than the robot file's joint speed limits
  (``vmax_deg_s``) and with accelerations of at most ``vmax / accel_time_s``; a datagram that is not a CORRECTION with six finite joints
  is counted and ignored;
* the arm: the robot file's ``[dynamics]`` and ``[axis_servo]`` through the Fanuc twin's plant
  (:class:`droid.arm.arm_dynamics.ArmDynamics`: the rigid body -- Pinocchio, or the compiled
  kernel's in droid-sim's world --, PI joint loops,
  amplifier limits, reducer compliance); ``dynamics = false`` puts an ideal arm on the reference;
* the sensor side silent for ``comm_timeout_s`` while guided: EGMRunJoint ends (``mciState``
  STOPPED), the reference path stops where it is and the joint loops bring the arm to rest on it
  (the twin's stop); the RAPID loop starts EGMRunJoint again ``restart_s`` later, from the arm's position;
* motors off (:meth:`EgmController.set_motors`): the holding brakes keep the arm where it is
  (the plant is not stepped), ``motorState`` MOTORS_OFF, no guidance; RAPID stopped
  (:meth:`set_rapid`): ``rapidExecState`` STOPPED, EGMRunJoint ends, feedback still streams.

Times are world time [s]; nothing here reads a clock.  The device (:class:`AbbEgmDevice`) owns
a non-blocking UDP socket on 127.0.0.1 and is stepped by ``Device.advance(dt_s)``.

Device type ``abb_egm`` (cell file)::

    [world.devices.abb]
    type = "abb_egm"
    subunit = "abb"             # whose egm URL (the sensor address) and robot file (default: the name)
    start_deg = [0, 0, 0, 0, 30, 0]   # joint angles at power-up [deg]
    period_s = 0.004            # EGM's sample period (250 Hz)
    comm_timeout_s = 1.0        # EGMSetupUC \\CommTimeout (ABB's default: 1 s)
    restart_s = 0.2             # the RAPID loop's pause before EGMRunJoint starts again
    convergence_deg = 0.1       # EGMActJoint's convergence band per joint (egm_minmax, +-0.1 deg)
    accel_time_s = 0.25         # the reference's time from rest to vmax_deg_s (ASSUMED)
    dynamics = true             # the robot file's arm (default: when the file has the tables)
    test_signals = false        # send EgmRobot.testSignals
"""
from __future__ import annotations

import errno
import ipaddress
import math
import socket
from dataclasses import dataclass

import numpy as np

from droid.brain.runtime.program import close_all
from droid.cli import BadInput
from droid.numbers import finite_numbers
from droid.kinematics import RobotModel, load_robot
from droid.kinematics.transforms import pose_to_T
from droid.sim.device import Device, cell_arm_subunit, number_options
from droid.arm.rigid_body import world_backend
from droid.sim.truth import TRUTH_PERIOD_S, TruthDoor, door_name
from droid.subunits.abb import egm_schema as es
from droid.subunits.abb.config import bind_udp, egm_config

OPTIONS = ("subunit", "start_deg", "period_s", "comm_timeout_s", "restart_s", "convergence_deg",
           "accel_time_s", "dynamics", "test_signals")
NUMBER_OPTIONS = ("period_s", "comm_timeout_s", "restart_s", "convergence_deg", "accel_time_s")
#: received datagrams read per world step, at most (a flood cannot stall the world)
MAX_READS_PER_STEP = 64
_U32 = 0xFFFFFFFF


@dataclass(frozen=True)
class EgmTwinParams:
    """The twin controller's EGM settings (ABB's defaults where ABB states one; docs/abb.md)."""

    period_s: float = 0.004  # EGM sends every 4 ms (250 Hz; ABB Application manual, EGM)
    comm_timeout_s: float = 1.0  # EGMSetupUC \CommTimeout default
    restart_s: float = 0.2  # DroidEGM.mod: WaitTime before EGMRunJoint runs again (ASSUMED)
    convergence_deg: float = 0.1  # DroidEGM.mod's egm_minmax of +-0.1 deg per joint
    accel_time_s: float = 0.25  # the reference reaches vmax_deg_s in this time, and stops in it (ASSUMED)
    dynamics: bool = True
    test_signals: bool = False

    def __post_init__(self) -> None:
        checks = (("period_s", 1e-4, 1.0), ("comm_timeout_s", 1e-3, 60.0), ("restart_s", 0.0, 60.0),
                  ("convergence_deg", 1e-6, 10.0), ("accel_time_s", 1e-3, 10.0))
        for name, lo, hi in checks:
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and lo <= v <= hi):
                raise ValueError(f"abb_egm: {name} must be in [{lo:g}, {hi:g}], got {v!r}")


class EgmController:
    """The controller; see the module docstring.  ``receive(data, t_s)``, ``advance(t_s)`` ->
    the EgmRobot datagrams due by then; read :attr:`q_deg` (the links) and :attr:`q_motor_deg`."""

    #: a reference at its target at rest is left as it is instead of ramped (the same bits: the
    #: ramp's arithmetic at e = 0, v = 0 returns them); False runs the ramp every step (tests)
    rest_shortcut = True

    def __init__(self, model: RobotModel, params: EgmTwinParams | None = None, q0_deg=None,
                 rigid_body: str = "pinocchio") -> None:
        self.model = model
        self.p = params or EgmTwinParams()
        q0 = np.zeros(6) if q0_deg is None else np.asarray(q0_deg, float).copy()
        if q0.shape != (6,) or not model.within_limits(q0):
            raise ValueError("abb_egm: the power-up joint angles must be 6 values inside the joint limits")
        self.arm = None
        if self.p.dynamics:
            from droid.arm.arm_dynamics import ArmDynamics

            self.arm = ArmDynamics(model, q0, rigid_body)
        self._q_ideal = q0.copy()
        self.qmin = np.asarray(model.joint_min_deg, float)
        self.qmax = np.asarray(model.joint_max_deg, float)
        self.vmax = np.asarray(model.vmax_deg_s, float)
        self.amax = self.vmax / self.p.accel_time_s  # [deg/s^2]
        self.ref_deg = q0.copy()  # the joint loops' reference (EgmRobot.planned)
        self.ref_rate = np.zeros(6)  # its rate [deg/s]
        self.target_deg: np.ndarray | None = None  # the newest sensor target
        self.t_s = 0.0
        self.motors_on = True
        self.rapid_running = True
        self.guiding = True  # EGMRunJoint active (MCI running)
        self.last_rx_s = 0.0  # the sensor's last good message (the guidance started "now")
        self.restart_at_s: float | None = None
        self.next_tx_s = 0.0
        self.tx_seqno = 0
        # counters (alike in shape only to droid-gmf1-serial's: each link counts its own events)
        self.received = 0
        self.bad = 0
        self.timeouts = 0
        self.sent = 0

    # -- state ---------------------------------------------------------------------------
    @property
    def q_deg(self) -> np.ndarray:
        """The links' joint angles [deg] (the truth)."""
        return self.arm.q_deg if self.arm is not None else self._q_ideal

    @property
    def q_motor_deg(self) -> np.ndarray:
        """What the resolvers measure, in joint degrees (the feedback)."""
        return self.arm.q_motor_deg if self.arm is not None else self._q_ideal

    def _stop_guiding(self, restart: bool, brakes: bool = False) -> None:
        """EGMRunJoint ends: the reference path stops where it is and the joint loops bring the
        arm to rest on it (``brakes``: the motors are off, the brakes hold the arm where it is)."""
        self.guiding = False
        self.target_deg = None
        if brakes:
            self.ref_deg = self.q_motor_deg.copy()
            self.ref_rate = np.zeros(6)
        self.restart_at_s = self.t_s + self.p.restart_s if restart else None

    def _start_guiding(self) -> None:
        self.guiding = True
        self.restart_at_s = None
        self.last_rx_s = self.t_s
        self.ref_deg = self.q_motor_deg.copy()
        self.ref_rate = np.zeros(6)
        self.target_deg = None

    def set_motors(self, on: bool) -> None:
        """Motors on/off (the FlexPendant's enabling device, an emergency stop and its reset)."""
        if on == self.motors_on:
            return
        self.motors_on = on
        if not on:
            self._stop_guiding(restart=False, brakes=True)
        elif self.rapid_running:
            self._start_guiding()

    def set_rapid(self, running: bool) -> None:
        """RAPID program started/stopped (EGMRunJoint runs only while it runs)."""
        if running == self.rapid_running:
            return
        self.rapid_running = running
        if not running:
            self._stop_guiding(restart=False)
        elif self.motors_on:
            self._start_guiding()

    @property
    def converged(self) -> bool:
        t = self.target_deg if self.target_deg is not None else self.ref_deg
        return bool(np.all(np.abs(self.q_motor_deg - t) <= self.p.convergence_deg))

    # -- the sensor side -----------------------------------------------------------------
    def receive(self, data: bytes, t_s: float) -> bool:
        """One datagram from the sensor at ``t_s`` [s]; True if it was a usable target."""
        msg = es.EgmSensor()
        try:
            msg.ParseFromString(bytes(data))
        except (es.DecodeError, ValueError, TypeError, RuntimeError):
            self.bad += 1
            return False
        joints = list(msg.planned.joints.joints)
        if msg.header.mtype != es.MSGTYPE_CORRECTION or len(joints) != 6 \
                or not all(math.isfinite(v) for v in joints):
            self.bad += 1
            return False
        self.received += 1
        if self.guiding:
            self.last_rx_s = t_s
            self.target_deg = np.minimum(np.maximum(np.array(joints, float), self.qmin), self.qmax)
        return True

    # -- time ----------------------------------------------------------------------------
    def advance(self, t_s: float) -> list[bytes]:
        """Run to ``t_s`` [s]: timeout and restart, the reference, the arm; the EgmRobot
        datagrams whose send time has come."""
        dt = max(0.0, t_s - self.t_s)
        self.t_s = t_s
        if self.guiding and t_s - self.last_rx_s > self.p.comm_timeout_s:
            self.timeouts += 1
            self._stop_guiding(restart=self.rapid_running and self.motors_on)
        if (not self.guiding and self.restart_at_s is not None and t_s >= self.restart_at_s
                and self.rapid_running and self.motors_on):
            self._start_guiding()
        if dt > 0 and self.motors_on:
            self._move_reference(dt)
        if self.motors_on:
            if self.arm is not None:
                self.arm.advance(t_s, self.ref_deg)
            else:
                self._q_ideal = self.ref_deg.copy()
        out = []
        while self.next_tx_s <= t_s + 1e-12:
            out.append(self.robot_message(self.next_tx_s))
            self.next_tx_s += self.p.period_s
        return out

    def _move_reference(self, dt: float) -> None:
        """The reference toward the target (or to rest, without one) within the joint speed
        limits (``vmax_deg_s``) and accelerations of ``vmax / accel_time_s``: at each joint the
        speed that can still stop on the target, ``sqrt(2 a |e|)``, reached at ``a`` at most."""
        v = self.ref_rate
        if self.guiding and self.target_deg is not None:
            if self.rest_shortcut and not v.any() and self.target_deg.tobytes() == self.ref_deg.tobytes():
                self.ref_rate = np.zeros(6)  # at the target at rest: what the ramp below leaves, bit for bit
                return
            dv = self.amax * dt
            e = self.target_deg - self.ref_deg
            want = np.sign(e) * np.minimum(self.vmax, np.sqrt(2.0 * self.amax * np.abs(e)))
            v = np.minimum(np.maximum(want, v - dv), v + dv)
            arrive = (np.abs(e) <= np.abs(v) * dt) & (np.abs(v) <= 2.0 * dv + 1e-12)
            self.ref_deg = np.where(arrive, self.target_deg, self.ref_deg + v * dt)
            self.ref_rate = np.where(arrive, 0.0, v)
        elif np.any(v):  # stopping: the path ramps down to rest
            dv = self.amax * dt
            v = np.sign(v) * np.maximum(np.abs(v) - dv, 0.0)
            self.ref_deg = self.ref_deg + v * dt
            self.ref_rate = v

    def robot_message(self, t_s: float) -> bytes:
        """The EgmRobot the controller sends at ``t_s`` [s]."""
        self.tx_seqno = (self.tx_seqno + 1) & _U32
        m = es.EgmRobot()
        m.header.seqno = self.tx_seqno
        m.header.tm = int(round(t_s * 1000.0)) & _U32
        m.header.mtype = es.MSGTYPE_DATA
        m.feedBack.joints.joints.extend(float(v) for v in self.q_motor_deg)
        usec = int(round(t_s * 1e6))
        m.feedBack.time.sec, m.feedBack.time.usec = usec // 1_000_000, usec % 1_000_000
        m.planned.joints.joints.extend(float(v) for v in self.ref_deg)
        m.motorState.state = es.MOTORS_ON if self.motors_on else es.MOTORS_OFF
        m.rapidExecState.state = es.RAPID_RUNNING if self.rapid_running else es.RAPID_STOPPED
        m.mciState.state = es.MCI_RUNNING if self.guiding else es.MCI_STOPPED
        m.mciConvergenceMet = self.converged
        if self.p.test_signals:
            m.testSignals.signals.extend(float(v) for v in self.ref_rate)
        self.sent += 1
        return m.SerializeToString()


class AbbEgmDevice(Device):
    """The controller core behind a UDP socket on 127.0.0.1, stepped by the world."""

    def __init__(self, name: str, controller: EgmController, sock: socket.socket, sensor_addr,
                 model_global: RobotModel, door=None) -> None:
        self.name = name
        self.controller = controller
        self.sock = sock
        self.sensor_addr = sensor_addr
        self.model_global = model_global
        self.t_s = 0.0
        self.send_errors = 0
        self.door = door  # the world's truth door for this arm (droid.sim.truth), or None
        self._truth_due_s = 0.0  # world time of the next truth-door write [s]

    @property
    def address(self) -> tuple[str, int]:
        """The controller's own UDP address (where droid-egm's replies go)."""
        return self.sock.getsockname()

    def advance(self, dt_s: float) -> None:
        t0 = self.t_s
        self.t_s = t1 = t0 + dt_s
        c = self.controller
        for _ in range(MAX_READS_PER_STEP):
            try:
                data, _src = self.sock.recvfrom(65536)
            except (BlockingIOError, InterruptedError):
                break
            except OSError:  # ECONNREFUSED of an earlier send (Linux reports it on the next call)
                continue
            c.receive(data, t0)
        for msg in c.advance(t1):
            try:
                self.sock.sendto(msg, self.sensor_addr)
            except OSError as exc:
                if exc.errno not in (errno.ECONNREFUSED, errno.EAGAIN, errno.ENOBUFS):
                    raise
                self.send_errors += 1
        if self.door is not None and t1 >= self._truth_due_s - 1e-9:  # the Reis twin's 250 Hz
            self._truth_due_s = t1 + TRUTH_PERIOD_S
            self.door.write(t1, c.q_deg, self.wcp_global()[:3, 3])

    def wcp_global(self) -> np.ndarray:
        """The true flange pose (4x4, mm) in the global frame: the model's FK frame (the
        arm-twin interface of the world; for this arm c4 = 85 mm: the flange, not the wrist)."""
        return self.model_global.fk(self.controller.q_deg)

    def close(self) -> None:
        sock, door, self.sock, self.door = self.sock, self.door, None, None
        close_all(sock, door)


def open_socket(port: int, where: str, host: str = "127.0.0.1") -> socket.socket:
    """A non-blocking UDP socket bound to ``host``:``port`` (a loopback address; port 0: any free port)."""
    return bind_udp((host, port), where)


def twin_params(options: dict, where: str, model: RobotModel) -> EgmTwinParams:
    has_dynamics = model.dynamics is not None and model.axis_servo is not None
    kw: dict = {"dynamics": has_dynamics}
    for key in ("dynamics", "test_signals"):
        if key in options:
            if not isinstance(options[key], bool):
                raise BadInput(f"{where} {key} must be true or false, got {options[key]!r}")
            kw[key] = options[key]
    if kw["dynamics"] and not has_dynamics:
        raise BadInput(f"{where} dynamics = true needs [dynamics] and [axis_servo] in the robot file {model.name}")
    kw.update(number_options(options, NUMBER_OPTIONS, where))
    try:
        return EgmTwinParams(**kw)
    except ValueError as exc:
        raise BadInput(f"{where} {exc}") from None


def egm_twin(cell, name: str, options: dict, rigid_body: str = "pinocchio") -> tuple[str, object, EgmController]:
    """The controller of a ``[world.devices.NAME]`` table of type ``abb_egm`` (the options
    without ``type``): ``(where, subunit, controller)``, before any socket -- the device below
    puts it behind UDP, ``droid.sim.abb.lockstep`` on a lockstep scheduler.  BadInput (one line)
    for an unknown option, a subunit that is not an arm, bad parameters or ``start_deg``."""
    where, sub = cell_arm_subunit(cell, name, options, OPTIONS)
    model = load_robot(sub.robot)
    params = twin_params(options, where, model)
    q0 = options.get("start_deg", [0.0] * 6)
    if not finite_numbers(q0, 6):
        raise BadInput(f"{where} start_deg must be 6 joint angles [deg]")
    why = model.limit_violation(np.array(q0, float))
    if why:
        raise BadInput(f"{where} start_deg outside the joint limits: {why}")
    return where, sub, EgmController(model, params, q0, rigid_body)


def make_abb_egm(world, name: str, options: dict) -> AbbEgmDevice:
    """Factory of the ``abb_egm`` device type (see the module docstring)."""
    cell = world.cell
    where, sub = cell_arm_subunit(cell, name, options, OPTIONS)
    cfg = egm_config(cell, sub)
    host = "127.0.0.1" if cfg.host == "localhost" else cfg.host
    try:
        loopback = ipaddress.ip_address(host).is_loopback
    except ValueError:
        loopback = False
    if not loopback:  # the cell's own loopback address ({loopback}) or 127.0.0.1
        raise BadInput(f"{where} the simulated controller talks to a loopback address (127.0.0.0/8) only; "
                       f"subunit {sub.name}'s egm host is {cfg.host!r}")
    _, _, controller = egm_twin(cell, name, options, world_backend())  # the world: no Pinocchio import
    sock = open_socket(0, where, host)  # any free port: the controller's source port is EGM's to choose
    try:  # `droid-sim truth SUBUNIT --json` and the benches read the true joints and flange here
        door = TruthDoor.create(door_name(cell.name, sub.name))
    except BaseException:
        sock.close()
        raise
    return AbbEgmDevice(name, controller, sock, (host, cfg.port), controller.model.with_base(pose_to_T(*sub.base)),
                        door)
