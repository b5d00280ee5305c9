"""droid-egm's core: the PC side of ABB's Externally Guided Motion, pure (issue 26, thesis §7.3).

Thesis §7.3 looks ahead to "robot controllers ... via Ethernet"; an ABB IRC5/OmniCore running
EGM is one: every 4 ms it sends an ``EgmRobot`` datagram (feedback joints in degrees, its
planned joints, motor / RAPID / MCI state, the convergence flag) to the sensor's address, and
it follows the joint targets of the ``EgmSensor`` datagrams that come back, until the sensor
side has been silent for its communication timeout.  This core is droid-egm without I/O:
datagrams (bytes, source address, receive time [ns]) in, reply datagrams out; the controller's
Command record (the planner's way-point, thesis §4.1.7) in, Status fields out (Table 4.2).  It
takes the place of the Reis's servo agent, servo and watchdog (docs/abb.md).

Datagrams (:meth:`EgmCore.datagram`): one longer than :data:`MAX_DATAGRAM_BYTES` is
*oversized*; one that does not decode, or lacks the header's sequence number or six finite
feedback joints, is *malformed* (a truncated datagram is one of these); a well-formed protobuf
that is not a robot's DATA message (an ``EgmSensor`` of another sensor, a stray message) is
*foreign*.  All three are counted and dropped: nothing is sent, nothing moves.  Sequence numbers
(``EgmHeader.seqno``, +1 per message, wrapping at 2^32): the newest sample wins; a gap counts
the missing numbers *lost*; a missing number that arrives afterwards is *reordered* (and no
longer lost); a number already received is *duplicated*; one older than the last
:data:`SEQ_WINDOW` numbers is *late*.  Each is dropped.  A sample from another source address
(the controller restarted EGM from another port, or another host) is a *reconnect*: it is
taken, whatever its number, and replies go to the newest source.  So is a sample far behind in
number but newer in the controller's clock (``EgmHeader.tm``: EGM restarted from the same
port), and the first sample after the link went stale.

Each accepted sample is answered at once with an ``EgmSensor``: the current joint target
[deg] and its rate [deg/s] (``speedRef``).  The target follows the planner's way-points,
interpolated linearly over one heartbeat period (the planner writes one per tick, 60 Hz; EGM
asks at 250 Hz), so the stream has no steps; it adds one heartbeat period of delay.

Each heartbeat period (:meth:`EgmCore.cycle`, on the relayed tick):

* the *stale rule* of every DROID link (``stale_ticks`` heartbeat periods without a sample,
  as the servo agent applies it to its servo, docs/architecture.md): FAULT_DEVICE (the link
  fault of this arm) and ``homed = 0`` -- the position is unknown, so the planner stops
  planning and re-anchors on the next sample (§4.1.7: it "suspends its execution until the
  robot has been homed");
* motors off, RAPID stopped or EGM's motion control (MCI) not running: FAULT_SERVO (the
  controller does not follow: the planner cancels the move and holds; tasks refuse to move);
  the target is re-anchored on the feedback, so nothing jumps when the controller resumes;
* the arm has absolute measurement (resolvers): while samples come it is ``homed``, and a
  HOME command is acknowledged at once (droid-home succeeds);
* NORMAL with the Brain link alive and the planner fresh: the target follows the planner's
  ``encoder_cmd_int`` (counts -> degrees through the robot file's gearing); a way-point farther
  from the target than two periods at the joints' speed limits is refused (FAULT_BRAKING: the
  planner re-anchors where the arm is, as it does for the Reis servo's braking); after any
  fault hold (and at start) a way-point is followed only once it lies within
  :data:`RESUME_DEG` of the feedback -- the planner has re-anchored -- so an old way-point
  left in the Command record is never driven to;
* otherwise (OFF, JOG, HOME, the Brain link lost, the planner silent) the target holds where it
  was commanded; a new JOG command moves it by its relative counts once (thesis §3.4); in
  OFF, JOG and HOME the planner follows the arm, so a fresh way-point at the feedback ends a
  fault hold's re-anchoring there too (a move commanded in the tick NORMAL returns, as a task
  does after droid-home, is followed from its first way-point);
* targets are clamped to the joint limits (FAULT_LIMIT while clamped).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, make_dataclass

import numpy as np

from droid.brain.db.layouts import (CMD_OK, FAULT_BRAKING, FAULT_DEVICE, FAULT_LIMIT, FAULT_SERVO, HOME_MODE,
                                 HOMED, JOG_MODE, NORMAL_MODE)
from droid.kinematics import RobotModel
from droid.subunits.abb import egm_schema as es
from droid.subunits.abb.egm_layout import COUNTERS

N = 6
#: a datagram longer than this is dropped unread [bytes] (an EgmRobot with every field is
#: about 400 bytes; one Ethernet payload holds 1472)
MAX_DATAGRAM_BYTES = 1472
#: sequence numbers remembered behind the newest one (missing / received) [messages]: 32 EGM
#: periods, 128 ms
SEQ_WINDOW = 32
#: |joint| above this in a datagram is malformed [deg] (the robot files' outer bound)
MAX_JOINT_DEG = 3600.0
#: the fault bits this program owns in the Status record (FAULT_LINK is the agent's)
MY_FAULTS = FAULT_DEVICE | FAULT_SERVO | FAULT_BRAKING | FAULT_LIMIT
#: slack on the way-point step check [deg]
STEP_SLACK_DEG = 0.1
#: after a fault hold, the planner's way-point is followed again only this close to the
#: feedback [deg] -- once the planner has re-anchored where the arm stands (the servo agent's
#: resume window)
RESUME_DEG = 0.05
_U32 = 0xFFFFFFFF
_HALF = 1 << 31


#: one int field per counter of the EGM record, in its order (generated from egm_layout.COUNTERS)
_CounterFields = make_dataclass("_CounterFields", [(name, int, 0) for name in COUNTERS])


class Counters(_CounterFields):
    """The link's counters: accepted, lost, late, duplicated, reordered, malformed, oversized,
    foreign, reconnects, replies (the fields come from egm_layout.COUNTERS, the record's list)."""

    @property
    def dropped(self) -> int:
        """Datagrams received and not taken (the presence record's bad_frames)."""
        return self.late + self.duplicated + self.reordered + self.malformed + self.oversized + self.foreign


@dataclass
class Sample:
    """One accepted EgmRobot."""

    seqno: int
    tm_ms: int
    rx_ns: int
    source: tuple
    feedback_deg: np.ndarray
    planned_deg: np.ndarray | None
    motor_state: int
    rapid_state: int
    mci_state: int
    convergence: int

    @property
    def guided(self) -> bool:
        """The controller follows targets: motors on, RAPID running, MCI not stopped/in error
        (a controller that does not report MCI state is taken at its motors and RAPID)."""
        return (self.motor_state == es.MOTORS_ON and self.rapid_state == es.RAPID_RUNNING
                and self.mci_state not in (es.MCI_STOPPED, es.MCI_ERROR))


class SeqTracker:
    """Sequence-number bookkeeping of one stream (see the module docstring).  Pure."""

    def __init__(self, window: int = SEQ_WINDOW) -> None:
        self.window = window
        self.newest: int | None = None
        self.missing: set[int] = set()  # numbers in the window not received yet

    def reset(self, seqno: int) -> None:
        self.newest, self.missing = seqno, set()

    def classify(self, seqno: int) -> str:
        """``"new"``, ``"duplicated"``, ``"reordered"`` or ``"late"``; updates the window.  A new
        number's gap is returned via :attr:`gap` (messages skipped)."""
        self.gap = 0
        if self.newest is None:
            self.reset(seqno)
            return "new"
        ahead = (seqno - self.newest) & _U32
        if ahead == 0:
            return "duplicated"
        if ahead < _HALF:
            self.gap = ahead - 1
            for k in range(1, min(ahead, self.window)):
                self.missing.add((seqno - k) & _U32)
            self.newest = seqno
            self.missing = {s for s in self.missing if (seqno - s) & _U32 < self.window}
            return "new"
        behind = (self.newest - seqno) & _U32
        if behind >= self.window:
            return "late"
        if seqno in self.missing:
            self.missing.discard(seqno)
            return "reordered"
        return "duplicated"


@dataclass
class EgmOutput:
    """One heartbeat period's result."""

    status: dict  # Status record fields (Table 4.2)
    fault_bits: int  # this program's bits (MY_FAULTS)
    egm: dict  # the EGM record's fields (egm_layout)
    replies: list = field(default_factory=list)  # (bytes, address) sent by step()
    why: str = ""  # why the target holds (a log line), "" when it follows or holds by command


def parse_robot(data: bytes) -> tuple[es.EgmRobot | None, str]:
    """The controller's ``EgmRobot`` DATA message in ``data``, or (None, why): ``oversized`` (>
    MAX_DATAGRAM_BYTES), ``malformed`` (does not decode, no header sequence number) or ``foreign``
    (not a DATA message).  Its feedback joints are not checked here."""
    if len(data) > MAX_DATAGRAM_BYTES:
        return None, "oversized"
    msg = es.EgmRobot()
    try:
        msg.ParseFromString(bytes(data))
    except (es.DecodeError, ValueError, TypeError, RuntimeError):
        return None, "malformed"
    if not msg.HasField("header") or not msg.header.HasField("seqno"):
        return None, "malformed"
    if msg.header.mtype != es.MSGTYPE_DATA:
        return None, "foreign"
    return msg, ""


def reported_joint_count(data: bytes) -> int | None:
    """How many feedback joints the controller's ``EgmRobot`` DATA message ``data`` carries, or
    None when it is not one (droid-egm compares it with the robot file's at start)."""
    msg, _ = parse_robot(data)
    return None if msg is None else len(msg.feedBack.joints.joints)


class EgmCore:
    """The PC side of one EGM link; see the module docstring.  Times are the caller's [ns]."""

    def __init__(self, model: RobotModel, stale_ticks: int, heartbeat_hz: float) -> None:
        self.model = model
        self.gearing = model.gearing
        self.period_ns = int(round(1e9 / heartbeat_hz))
        self.stale_ticks = int(stale_ticks)
        self.stale_ns = self.stale_ticks * self.period_ns
        self.qmin = np.asarray(model.joint_min_deg, float)
        self.qmax = np.asarray(model.joint_max_deg, float)
        self.max_step_deg = np.asarray(model.vmax_deg_s, float) * 2.0 / heartbeat_hz + STEP_SLACK_DEG
        self.counters = Counters()
        self.seq = SeqTracker()
        self.sample: Sample | None = None
        self.source: tuple | None = None  # where replies go: the newest sample's source
        self.tx_seqno = 0
        # the target: a hold point, or a way-point pair interpolated over one period
        self.hold_deg: np.ndarray | None = None
        self.wp_from: np.ndarray | None = None
        self.wp_to: np.ndarray | None = None
        self.wp_ns = 0
        self.wp_tick: int | None = None  # planner_tick of wp_to
        self.clamped = False
        self.reanchor = True  # a fault hold: wait for the planner's way-point at the arm
        self.jog_id: int | None = None
        self.home_id: int | None = None
        self.last_fault_bits = 0

    # -- the target ------------------------------------------------------------------
    def _clamp(self, q: np.ndarray) -> np.ndarray:
        c = np.minimum(np.maximum(q, self.qmin), self.qmax)
        self.clamped = bool(np.any(c != q))
        return c

    def target(self, now_ns: int) -> tuple[np.ndarray | None, np.ndarray]:
        """The joint target [deg] at ``now_ns`` and its rate [deg/s] (None before any sample)."""
        if self.wp_to is not None:
            frac = min(1.0, max(0.0, (now_ns - self.wp_ns) / self.period_ns))
            q = self.wp_from + (self.wp_to - self.wp_from) * frac
            rate = (self.wp_to - self.wp_from) * (1e9 / self.period_ns) if frac < 1.0 else np.zeros(N)
            return q, rate
        if self.hold_deg is not None:
            return self.hold_deg, np.zeros(N)
        if self.sample is not None:
            return self.sample.feedback_deg, np.zeros(N)
        return None, np.zeros(N)

    def _hold(self, q_deg) -> None:
        self.hold_deg = self._clamp(np.asarray(q_deg, float).copy())
        self.wp_from = self.wp_to = None
        self.wp_tick = None

    # -- datagrams ---------------------------------------------------------------------
    def _decode(self, data: bytes) -> es.EgmRobot | None:
        """The EgmRobot in ``data``, or None (counted: oversized, malformed or foreign)."""
        msg, why = parse_robot(data)
        if msg is None:
            setattr(self.counters, why, getattr(self.counters, why) + 1)
            return None
        joints = msg.feedBack.joints.joints
        if len(joints) != N or not all(math.isfinite(v) and abs(v) <= MAX_JOINT_DEG for v in joints):
            self.counters.malformed += 1
            return None
        return msg

    def datagram(self, data: bytes, source: tuple, now_ns: int) -> tuple[bytes, tuple] | None:
        """One UDP datagram from ``source`` received at ``now_ns``; returns the reply (EgmSensor
        bytes, address) to send, or None (nothing is sent for a dropped datagram)."""
        msg = self._decode(data)
        if msg is None:
            return None
        seqno, tm = int(msg.header.seqno), int(msg.header.tm)
        fresh = self.sample is not None and now_ns - self.sample.rx_ns < self.stale_ns
        reconnect = (self.sample is None or source != self.source or not fresh)
        if not reconnect:
            kind = self.seq.classify(seqno)
            if kind == "late" and ((tm - self.sample.tm_ms) & _U32) < _HALF and tm != self.sample.tm_ms:
                reconnect = True  # EGM restarted on the same port: numbers begin again, its clock runs on
            elif kind != "new":
                setattr(self.counters, kind, getattr(self.counters, kind) + 1)
                if kind == "reordered":
                    self.counters.lost -= 1  # counted lost when its gap opened; it came after all
                return None
            else:
                self.counters.lost += self.seq.gap
        if reconnect:
            if self.sample is not None:
                self.counters.reconnects += 1
            self.seq.reset(seqno)
        self.counters.accepted += 1
        planned = list(msg.planned.joints.joints)
        self.sample = Sample(
            seqno=seqno, tm_ms=tm, rx_ns=now_ns, source=source,
            feedback_deg=np.array(msg.feedBack.joints.joints, float),
            planned_deg=np.array(planned, float) if len(planned) == N and all(map(math.isfinite, planned)) else None,
            motor_state=int(msg.motorState.state), rapid_state=int(msg.rapidExecState.state),
            mci_state=int(msg.mciState.state), convergence=int(msg.mciConvergenceMet))
        self.source = source
        return self.reply(now_ns), source

    def reply(self, now_ns: int) -> bytes:
        """The EgmSensor for the controller at ``now_ns``: the target [deg] and its rate [deg/s]."""
        q, rate = self.target(now_ns)
        self.tx_seqno = (self.tx_seqno + 1) & _U32
        msg = es.EgmSensor()
        msg.header.seqno = self.tx_seqno
        msg.header.tm = (now_ns // 1_000_000) & _U32
        msg.header.mtype = es.MSGTYPE_CORRECTION
        msg.planned.joints.joints.extend(float(v) for v in q)
        msg.speedRef.joints.joints.extend(float(v) for v in rate)
        self.counters.replies += 1
        return msg.SerializeToString()

    # -- the heartbeat period -------------------------------------------------------------
    def cycle(self, cmd, now_ns: int, late_ns: int = 0) -> EgmOutput:
        """One heartbeat period: ``cmd`` the controller's Command record (Table 4.3).  ``late_ns``:
        how late this cycle itself runs (a stalled host): the silence is judged only over time
        this program was awake to hear it, as the servo agent does (issue 16)."""
        s = self.sample
        status: dict = {"cmd_mode": int(cmd["cmd_mode"]), "coord": int(cmd["coord"])}
        faults = 0
        why = ""
        mode, cmd_id = int(cmd["cmd_mode"]), int(cmd["cmd_id"])
        if self.jog_id is None:  # a JOG issued before we started is not replayed (a HOME is: it
            self.jog_id = cmd_id  # moves nothing on this arm, and its task may be waiting for it)
        fresh = s is not None and now_ns - s.rx_ns < self.stale_ns + max(0, int(late_ns))
        if not fresh:
            faults |= FAULT_DEVICE
            status["homed"] = 0
            why = "no EGM feedback" if s is None else "EGM feedback stale"
            if s is not None:
                self._hold(s.feedback_deg)
            self.reanchor = True
        else:
            status["homed"] = HOMED  # absolute measurement: homed while the position is known
            status["encoder_pos"] = np.rint(self.gearing.joints_to_counts(s.feedback_deg)).astype(np.int32)
            if not s.guided:
                faults |= FAULT_SERVO
                why = "controller not guiding (motors off, RAPID stopped or EGM not running)"
                self._hold(s.feedback_deg)
                self.reanchor = True
            elif mode == NORMAL_MODE and int(cmd["link_alive"]) and \
                    int(cmd["brain_tick"]) - int(cmd["planner_tick"]) <= self.stale_ticks:
                planner_tick = int(cmd["planner_tick"])
                if planner_tick != self.wp_tick:
                    wp = self.gearing.counts_to_joints(np.asarray(cmd["encoder_cmd_int"], float))
                    here, _ = self.target(now_ns)
                    if self.reanchor and np.any(np.abs(wp - s.feedback_deg) > RESUME_DEG):
                        why = "waiting for the planner to re-anchor"  # an old way-point: never resumed
                        self._hold(s.feedback_deg)  # meanwhile: where the arm stands
                    elif np.any(np.abs(wp - here) > self.max_step_deg):
                        faults |= FAULT_BRAKING  # the planner re-anchors where the arm is
                        why = "way-point too far from the target"
                        self._hold(s.feedback_deg)
                        self.reanchor = True
                    else:
                        self.reanchor = False
                        self.wp_from, self.wp_to = here.copy(), self._clamp(wp)
                        self.wp_ns, self.wp_tick = now_ns, planner_tick
                        self.hold_deg = None
            else:
                if self.wp_to is not None:  # stop where the stream was: the end of the interpolation
                    q, _ = self.target(now_ns)
                    self._hold(q)
                    if mode == NORMAL_MODE:
                        why = "Brain link lost" if not int(cmd["link_alive"]) else "planner silent"
                elif self.hold_deg is None:
                    self._hold(s.feedback_deg)
                if mode == JOG_MODE and cmd_id != self.jog_id:
                    self.jog_id = cmd_id
                    delta = self.gearing.counts_to_joints(np.asarray(cmd["encoder_cmd_ext"], float))
                    self._hold(self.hold_deg + delta)
                    status.update(cmd_id=cmd_id, cmd_result=CMD_OK, busy=0)
                if mode != NORMAL_MODE and self._planner_at_arm(cmd, s):
                    self.reanchor = False  # JOG/HOME/OFF: the planner follows the arm (§4.1.7)
            if mode == HOME_MODE and cmd_id != self.home_id:
                self.home_id = cmd_id
                status.update(cmd_id=cmd_id, cmd_result=CMD_OK, busy=0)
        if mode == HOME_MODE and not fresh and cmd_id != self.home_id:
            status["busy"] = 1  # acknowledged once the position is known
        if self.clamped:
            faults |= FAULT_LIMIT
        q, _ = self.target(now_ns)
        if q is not None:
            status["encoder_cmd"] = np.rint(self.gearing.joints_to_counts(q)).astype(np.int32)
        self.last_fault_bits = faults
        return EgmOutput(status, faults, self.egm_fields(now_ns), why=why)

    def _planner_at_arm(self, cmd, s: Sample) -> bool:
        """The planner is fresh and its way-point lies within RESUME_DEG of the feedback: it has
        re-anchored where the arm stands, so the next NORMAL move starts from the arm (one
        commanded in the very tick NORMAL returns, after droid-home, is followed at once)."""
        if int(cmd["brain_tick"]) - int(cmd["planner_tick"]) > self.stale_ticks:
            return False
        wp = self.gearing.counts_to_joints(np.asarray(cmd["encoder_cmd_int"], float))
        return bool(np.all(np.abs(wp - s.feedback_deg) <= RESUME_DEG))

    def step(self, datagrams, cmd, now_ns: int, late_ns: int = 0) -> EgmOutput:
        """The whole core in one call: every datagram ``(bytes, source, rx_ns)`` received since
        the last period, then the period's cycle at ``now_ns``.  The replies are in the output."""
        replies = []
        for data, source, rx_ns in datagrams:
            r = self.datagram(data, source, rx_ns)
            if r is not None:
                replies.append(r)
        out = self.cycle(cmd, now_ns, late_ns)
        out.replies = replies
        return out

    def egm_fields(self, now_ns: int) -> dict:
        """The EGM record's fields (egm_layout.EGM_STATUS) at ``now_ns``."""
        s = self.sample
        q, _ = self.target(now_ns)
        f = {name: getattr(self.counters, name) for name in COUNTERS}
        f["updated_ns"] = now_ns
        if q is not None:
            f["target_deg"] = q
        if s is not None:
            f.update(feedback_deg=s.feedback_deg, motor_state=s.motor_state, rapid_state=s.rapid_state,
                     mci_state=s.mci_state, convergence=s.convergence, seqno=s.seqno, tm_ms=s.tm_ms,
                     sample_age_us=min(_U32, max(0, (now_ns - s.rx_ns) // 1000)),
                     source_port=int(s.source[1]) if len(s.source) > 1 else 0)
            if s.planned_deg is not None:
                f["planned_deg"] = s.planned_deg
        return f
