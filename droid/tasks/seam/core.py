"""The dynamic seam-tracking core (thesis §5.1-5.2, §5.5, eq. 5.1-5.11; §6.1.1; §6.2.5).

One :meth:`SeamTracker.step` per seam-tracking cycle (30 Hz: every second
60 Hz heartbeat tick).  Pure: poses and a sensor reading in, two wrist-centre
commands (or a stop) out; no I/O, no clock.  The functions of the thesis's
``seamtrack`` program (§5.5.2, Figure 5.9 and the listings) are methods of
the same names:

===========================  ===========================================================
``holder_robot_wcp``         the GMF1 wrist-centre pose (global): ``global T (GMF1)6``
``tool_robot_wcp_wrt_holder``  eq. 5.10: ``(GMF1)6 T (Reis)6``
``toolpt_wrt_holder``        eq. 5.5: ``(GMF1)6 T tool = (GMF1)6 T (Reis)6 (Reis)6 T tool``
``update_seam_wrt_holder``   eq. 5.1/5.3 with the yaw and pitch corrections (eq. 5.6-5.7):
                             the newest seam frame at the front of the dynamic seam patch
``interpolate``              §5.2/Figure 5.4: the target tool pose, ``vel`` mm further along
                             the patch, orientation of the patch's front
``gen_tool_robot_wcp``       eq. 5.11: the Reis wrist-centre command (global)
``gen_hold_robot_wcp``       the GMF1 wrist-centre command: hold the pose it had at the start
``write_robot_cmd``          packs both commands into the cycle's :class:`CycleOutput`
===========================  ===========================================================

Frames (docs/mvs.md): the sensor frame S and the tool frame T have x along
the tool axis toward the surface (depth), y lateral (left), z the travel
direction.  A reading (x, y, roll) gives ``sensor T seam = Trans(x, y, 0)
Rz(roll)`` (the listing's ``Tmvs``, built by the Brain from the MVS Status).

Faithful to the listing, including its quirks:

* the seam patch is a queue of 4x4 frames in the GMF1 wrist frame, newest
  (the camera) at index 0; ``tcp_idx`` indexes the oldest frame still behind
  the tool; at most ``max_queue`` + 1 frames are kept (``MAX_QUEUE``);
* on the first cycle the patch is seeded with the *tool point* itself, so the
  tool first heads straight for the point where the sensor started: the
  initial straight section of §6.1.1 ("once ... the tool center point has
  reached the point on the seam at which the sensor started, any path can be
  tracked") is the natural start of the queue, not a separate mode;
* for ``dead_zone_cycles`` cycles (30 in the listing) the sensor is not read
  and ``Tmvs`` stays the identity: the camera's own frame enters the patch;
* yaw = -(y / CAMERA_TO_TCP) * k_yaw about the seam frame's x axis and
  pitch = (x / CAMERA_TO_TCP) * k_pitch about its y axis (the listing's
  small-angle form of eq. 5.6-5.7);
* the target orientation is the front of the patch (the frame at the
  camera), so the corrections turn the wrist about the tool point: the camera
  is steered back onto the seam while the tool follows the recorded patch;
* invalid sensor data -> x, y, roll = 0 (§6.2.5): the tracker goes straight on.

Additions (documented in docs/seamtrack.md): stop reasons -- the run length
reached ("end of seam"), the lead sensor invalid for more than
``lost_cycles`` consecutive cycles after the dead zone ("seam lost"), a Reis
command outside the robot model's reach or limits ("unreachable"), a tool that
moved faster than RUNAWAY_FACTOR times the speed for two seconds ("runaway"), an
arm whose Status reports a fault it cannot move with ("fault": the rule is
droid.tasks.seam.cycle.arm_faults; the shells ask it before each cycle and stop the
core with :meth:`SeamTracker.halt`); and the transport-delay buffer of §6.2.5
(:mod:`droid.tasks.seam.delay`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from droid.kinematics import RobotModel, Unreachable
from droid.kinematics.transforms import inv_homo, rotx, roty
from droid.tasks.seam.delay import DELAY_OFF, INVALID_READING, Reading, TransportDelay
from droid.tasks.seam.guard import TravelGuard
from droid.tasks.seam.ik import hinted_ik
from droid.tasks.seam.params import (DEAD_ZONE_CYCLES, MODE_LISTING, PHASE_DEAD_ZONE, PHASE_INITIAL, PHASE_TRACKING,
                                     SeamParams)
from droid.tasks.seam.patch import SeamPatch, nearest_segment
from droid.tasks.seam.stops import STOP_LOST, STOP_UNREACHABLE, TrackingStop


@dataclass(frozen=True)
class CycleOutput:
    """What one seam-tracking cycle produced."""

    cycle: int
    tool_cmd: np.ndarray | None  # the tool robot's WCP command, 4x4 global [mm]; None once stopped
    hold_cmd: np.ndarray | None  # the holder's WCP command, 4x4 global [mm]; None once stopped
    stop: TrackingStop | None
    phase: str
    travel_mm: float  # tool travel since the start, in the holder's wrist frame [mm]
    yaw_rad: float  # the correction applied this cycle (gain included)
    pitch_rad: float
    reading: Reading  # the reading used (after the invalid rule and the delay buffer)
    delay_state: str
    tcp_idx: int
    queue_len: int
    q_tool_deg: np.ndarray | None = None  # the tool robot's joints [deg] for tool_cmd (None without a model)


@dataclass
class _State:
    cycle: int = 0
    dead_zone: int = DEAD_ZONE_CYCLES
    first: bool = True
    tcp_idx: int = 0
    invalid_run: int = 0
    initial_done: bool = False
    pushes: int = 0
    q_prev: np.ndarray | None = None
    hold_cmd: np.ndarray | None = None
    stop: TrackingStop | None = None
    seam_pos: SeamPatch = field(default_factory=SeamPatch)  # positions (x, y, z) of the patch, index 0 newest
    seam_front: np.ndarray | None = None  # the newest patch frame (4x4)
    travel: TravelGuard | None = None  # set by SeamTracker from its parameters

    @property
    def travel_mm(self) -> float:
        """Tool travel since the start [mm]."""
        return self.travel.travel_mm


def mount(tracker, params: SeamParams, T_wcp_tool, T_wcp_sensor, tool_model: RobotModel | None) -> None:
    """What every tracker core (thesis, listing, plus) keeps of its set-up: the parameters,
    the tool and sensor transforms on the Reis wrist [mm], the camera-to-tool distance [mm],
    the Reis model for reachability and the transport-delay buffer (§5.5)."""
    tracker.p = params
    tracker.T67tool = np.asarray(T_wcp_tool, float)
    tracker.Tcamera_6 = np.asarray(T_wcp_sensor, float)
    tracker.T67tool_inv = inv_homo(tracker.T67tool)
    tracker.camera_to_tcp_mm = float(np.linalg.norm(tracker.Tcamera_6[:3, 3] - tracker.T67tool[:3, 3]))
    if not tracker.camera_to_tcp_mm > 0:
        raise ValueError("the sensor's measuring point coincides with the tool point")
    tracker.tool_model = tool_model
    tracker.delay = TransportDelay(params.delay_cycles, params.delay_at_mm)


class SeamTracker:
    """The seamtrack core (see the module docstring).

    ``T_wcp_tool``: ``(Reis)6 T tool`` (the listing's T67tool);
    ``T_wcp_sensor``: ``(Reis)6 T sensor`` (Tcamera_6); ``tool_model``: the
    Reis robot model *with its base* (commands are global), used to refuse an
    unreachable command before it is sent (None: no check).
    """

    def __init__(self, params: SeamParams, T_wcp_tool, T_wcp_sensor, tool_model: RobotModel | None = None):
        mount(self, params, T_wcp_tool, T_wcp_sensor, tool_model)
        self.s = _State(dead_zone=params.dead_zone_cycles, travel=TravelGuard(params))
        # the listing's globals
        self.T06hold = np.eye(4)  # global T (GMF1)6
        self.T6tool_hold = np.eye(4)  # (GMF1)6 T (Reis)6
        self.Ttool7_hold = np.eye(4)  # (GMF1)6 T tool
        self.T_sensor_seam = np.eye(4)  # sensor T seam (the listing's Tmvs)
        self._hold_inv_key, self._hold_inv = None, None  # global T (GMF1)6 (bytes) and its inverse
        self._T6tool_hold_sensed = None  # (GMF1)6 T (Reis)6 when the reading was taken (None: now)
        self._sensed_inv_key, self._sensed_inv = None, None  # the holder's sensed pose (bytes), its inverse

    # ------------------------------------------------------------ listing functions
    def holder_robot_wcp(self, T_global_hold6) -> np.ndarray:
        """The workpiece holder's wrist centre in the global frame, ``global T (GMF1)6`` (§5.5.2)."""
        self.T06hold = np.asarray(T_global_hold6, float)
        return self.T06hold

    def tool_robot_wcp_wrt_holder(self, T_global_tool6) -> np.ndarray:
        """Eq. 5.10: the Reis wrist centre w.r.t. the GMF1's, ``(GMF1)6 T (Reis)6``.

        ``(global T (GMF1)0 (GMF1)0 T 6)^-1  global T (Reis)0 (Reis)0 T 6``; the
        Status poses already include the bases (global frame, Table 3.1).
        """
        key = self.T06hold.tobytes()  # the holder usually stands still: invert a new pose only
        if key != self._hold_inv_key:
            self._hold_inv_key, self._hold_inv = key, inv_homo(self.T06hold)
        self.T6tool_hold = self._hold_inv @ np.asarray(T_global_tool6, float)
        return self.T6tool_hold

    def toolpt_wrt_holder(self) -> np.ndarray:
        """Eq. 5.5: the tool point w.r.t. the GMF1's wrist centre, ``(GMF1)6 T (Reis)6 (Reis)6 T tool``."""
        self.Ttool7_hold = self.T6tool_hold @ self.T67tool
        return self.Ttool7_hold

    def update_seam_wrt_holder(self, reading: Reading) -> tuple[float, float]:
        """Eq. 5.1/5.3 + 5.6/5.7: push the newest seam frame onto the front of the patch.

        ``(GMF1)6 T seam = (GMF1)6 T (Reis)6  (Reis)6 T sensor  sensor T seam  Tpitch  Tyaw``
        with yaw = -(y / CAMERA_TO_TCP) k_yaw about x and pitch = (x /
        CAMERA_TO_TCP) k_pitch about y.  The sensor is not read during the
        dead zone (``T_sensor_seam`` stays as it was: the identity).  Returns (yaw,
        pitch) [rad].
        """
        s = self.s
        if s.first:  # seed the patch with the tool point (the listing's Treis7_gmf1)
            s.first = False
            s.seam_pos = SeamPatch([tuple(self.Ttool7_hold[:3, 3])])
            s.seam_front = self.Ttool7_hold.copy()
        if s.dead_zone > 0:
            s.dead_zone -= 1
        else:
            s.dead_zone = 0
            self.T_sensor_seam = _seam_transform(reading)
        L = self.camera_to_tcp_mm
        yaw = -(self.T_sensor_seam[1, 3] / L) * self.p.yaw_gain
        pitch = (self.T_sensor_seam[0, 3] / L) * self.p.pitch_gain
        T6tool_hold = self.T6tool_hold if self._T6tool_hold_sensed is None else self._T6tool_hold_sensed
        frame = T6tool_hold @ self.Tcamera_6 @ self.T_sensor_seam @ roty(pitch) @ rotx(yaw)
        # rotating the seam queue: seam[i+1] = seam[i] for i = tcp_idx .. 0, seam[0] = newest
        s.seam_pos.push_front((float(frame[0, 3]), float(frame[1, 3]), float(frame[2, 3])))
        s.seam_front = frame
        s.tcp_idx += 1
        s.pushes += 1
        s.seam_pos.keep(min(s.tcp_idx, self.p.max_queue + 1) + 1)
        return yaw, pitch

    #: the patch's segment nearest the tool point (:func:`nearest_segment`); an experiment may
    #: put a compiled one of the same bits here (droid.experiments.seam_kernel)
    nearest = staticmethod(nearest_segment)

    def interpolate(self, vel_mm: float) -> np.ndarray:
        """§5.2/Figure 5.4: the target tool pose w.r.t. the GMF1 wrist, ``vel_mm`` further along the patch.

        ``thesis`` mode: :meth:`interpolate_thesis`; ``listing`` mode: :meth:`interpolate_listing`.
        """
        if self.p.mode == MODE_LISTING:
            return self.interpolate_listing(vel_mm)
        return self.interpolate_thesis(vel_mm)

    def interpolate_thesis(self, vel_mm: float) -> np.ndarray:
        """§5.2 as the text describes the patch: it holds the seam "from the point directly
        below the current camera position to the current tool tip location".

        The tool point is projected onto the nearest segment of the patch (the whole patch
        is searched: no bracketing test that fails once the tool is off the recorded path by
        more than the points' spacing); the target is ``vel_mm`` further along the patch
        from that projection, walking the segments toward the camera (the front's
        position if the patch ends first).  ``tcp_idx`` becomes the index of the older end
        of the tool's segment, so everything from the camera to the tool is kept.  The
        orientation is the patch's front, as the listing.
        """
        s = self.s
        seam = s.seam_pos
        tool = self.Ttool7_hold[:3, 3]
        out = np.array(s.seam_front)
        n = len(seam)
        if n < 2:
            d = np.asarray(seam[0]) - tool if n else np.zeros(3)
            dist = float(np.linalg.norm(d))
            out[:3, 3] = tool + (d * min(1.0, vel_mm / dist) if dist > 1e-9 else 0.0)
            return out
        P = seam.array  # index 0 newest
        a = P[1:]  # segment j: from the older a[j] = seam[j+1] to the newer seam[j]
        ab, den, ok = seam.segments()  # ab = seam[j] - a[j], |ab|^2 (or 1.0) and |ab|^2 > 1e-18
        j, pos = self.nearest(tool, a, ab, den, ok)
        nearest = j
        left = float(vel_mm)
        target = None
        while True:
            seg = P[j] - pos
            ls = math.sqrt(float(seg.dot(seg)))  # np.linalg.norm(seg), without its overhead
            if ls >= left and ls > 1e-12:
                target = pos + seg * (left / ls)
                break
            left -= ls
            pos = P[j]
            if j == 0:
                target = pos  # the patch ends at the camera's newest point
                break
            j -= 1
        out[:3, 3] = target
        idx = nearest + 1
        s.tcp_idx = min(max(idx, 1), self.p.max_queue)
        if not s.initial_done and s.tcp_idx - 1 < s.pushes - 1:
            s.initial_done = True  # the tool has passed the point where the sensor started
        return out

    def interpolate_listing(self, vel_mm: float) -> np.ndarray:
        """The literal port of the listing's ``interpolate()`` (``--mode listing``).

        Walks the patch from ``tcp_idx`` toward the camera for the two frames
        bounding the tool point (or the first one closer than ``vel``), then
        steps ``vel`` from the tool point toward the newer one.  The
        orientation is the patch's front (the newest seam frame).  The
        listing, including its index clamps.
        """
        s = self.s
        seam = s.seam_pos
        tool = self.Ttool7_hold[:3, 3]
        tx, ty, tz = float(tool[0]), float(tool[1]), float(tool[2])
        mq = self.p.max_queue
        idx = min(max(s.tcp_idx, 1), mq, len(seam) - 1)

        def dists(i: int):
            px, py, pz = seam[i]
            nx, ny, nz = seam[i - 1]
            nd = (nx - tx, ny - ty, nz - tz)
            return (math.dist((px, py, pz), (tx, ty, tz)), nd, math.hypot(*nd),
                    math.dist((nx, ny, nz), (px, py, pz)))

        prev_dist, next_d, next_dist, btwn_dist = dists(idx)
        found = False
        while not found and idx > 1:
            if prev_dist < btwn_dist and next_dist < btwn_dist:
                found = True
            elif next_dist < vel_mm:
                found = True
                idx -= 1
            else:
                idx -= 1
            prev_dist, next_d, next_dist, btwn_dist = dists(idx)
        s.tcp_idx = min(max(idx, 1), mq - 1) if idx > mq else max(idx, 1)
        out = np.array(s.seam_front)
        if next_dist > 1e-9:
            k = vel_mm / next_dist
            out[:3, 3] = (tx + k * next_d[0], ty + k * next_d[1], tz + k * next_d[2])
        else:
            out[:3, 3] = (tx, ty, tz)
        if not s.initial_done and idx - 1 < s.pushes - 1:
            s.initial_done = True  # the tool has passed the point where the sensor started
        return out

    def gen_tool_robot_wcp(self, Ttool7_hold_new) -> np.ndarray:
        """Eq. 5.11: the Reis wrist-centre command, ``global T (GMF1)6 (GMF1)6 T tool ((Reis)6 T tool)^-1``."""
        return self.T06hold @ np.asarray(Ttool7_hold_new, float) @ self.T67tool_inv

    def gen_hold_robot_wcp(self) -> np.ndarray:
        """The GMF1 wrist-centre command: hold the pose it had at the start of the run.

        The thesis's gen_hold_robot_wcp() "determines the new position and pose
        of the workpiece holder robot's WCP" but its code is not listed; in
        every experiment the workpiece stays still on the GMF1's tool plate
        (§6.1.1), so the holder is commanded to stay where it started.
        """
        if self.s.hold_cmd is None:
            self.s.hold_cmd = self.T06hold.copy()
        return self.s.hold_cmd

    def write_robot_cmd(self, tool_cmd, hold_cmd, **fields) -> CycleOutput:
        """Both robot commands of this cycle, as the shell writes them (cart commands, one cycle long)."""
        return CycleOutput(tool_cmd=tool_cmd, hold_cmd=hold_cmd, **fields)

    # ------------------------------------------------------------ one cycle
    @property
    def stopped(self) -> TrackingStop | None:
        return self.s.stop

    def step(self, T_global_hold6, T_global_tool6, reading: Reading, q_tool_deg=None,
             elapsed_cycles: float = 1.0, T_global_tool6_sensed=None, T_global_hold6_sensed=None) -> CycleOutput:
        """One 30 Hz cycle.

        ``T_global_hold6``, ``T_global_tool6``: the GMF1 and Reis wrist-centre
        poses (4x4, mm, global, from their Status records); ``reading``: the
        lead sensor's reading (invalid -> zeros); ``q_tool_deg``: the Reis's
        joint angles [deg] (the first cycle's IK hint; later the previous
        pick is used, as the planner does); ``elapsed_cycles``: how many
        cycles of time lie between this Reis pose and the last one (a late
        Status counts more than one: the runaway guard scales with it);
        ``T_global_tool6_sensed``: the Reis pose when the sensor took the
        reading (eq. 5.3 places the reading with the camera pose of its own
        instant; a real-time shell whose readings arrive later than the pose
        passes the pose of the reading's time -- an addition; None: the
        current pose, as the listing); ``T_global_hold6_sensed``: the GMF1 pose at
        that instant (None: the current one).
        """
        s = self.s
        cycle = s.cycle
        s.cycle += 1
        if s.stop is not None:
            return self._stopped_output(cycle)
        self.holder_robot_wcp(T_global_hold6)
        self.tool_robot_wcp_wrt_holder(T_global_tool6)
        self.toolpt_wrt_holder()
        tool = self.Ttool7_hold[:3, 3].copy()
        stop = s.travel.step(tool, elapsed_cycles, guard_runaway=s.dead_zone == 0)  # (the arm may settle first)
        if stop:
            return self._stop(cycle, *stop)
        if s.q_prev is None and q_tool_deg is not None:
            s.q_prev = np.asarray(q_tool_deg, float)

        in_dead_zone = s.dead_zone > 0
        if not reading.valid:
            reading = INVALID_READING  # §6.2.5: invalid data -> x, y, roll = 0
        used, delay_state = self.delay.filter(reading, s.travel_mm)
        if not in_dead_zone:
            s.invalid_run = 0 if used.valid else s.invalid_run + 1
            if s.invalid_run > self.p.lost_cycles:
                return self._stop(cycle, STOP_LOST, f"lead sensor invalid for {s.invalid_run} cycles")
        hold_inv = self._hold_inv if T_global_hold6_sensed is None else self._sensed_hold_inv(T_global_hold6_sensed)
        self._T6tool_hold_sensed = None if T_global_tool6_sensed is None else \
            hold_inv @ np.asarray(T_global_tool6_sensed, float)
        yaw, pitch = self.update_seam_wrt_holder(used)
        target = self.interpolate(self.p.step_mm)
        tool_cmd = self.gen_tool_robot_wcp(target)
        try:
            q = hinted_ik(self.tool_model, tool_cmd, s.q_prev)
        except (Unreachable, ValueError) as exc:
            return self._stop(cycle, STOP_UNREACHABLE, str(exc))
        if q is not None:
            s.q_prev = q
        phase = PHASE_DEAD_ZONE if in_dead_zone else (PHASE_TRACKING if s.initial_done else PHASE_INITIAL)
        return self.write_robot_cmd(
            tool_cmd, self.gen_hold_robot_wcp(), cycle=cycle, stop=None, phase=phase,
            travel_mm=s.travel_mm, yaw_rad=yaw, pitch_rad=pitch, reading=used, delay_state=delay_state,
            tcp_idx=s.tcp_idx, queue_len=len(s.seam_pos), q_tool_deg=q)

    def _sensed_hold_inv(self, T_global_hold6_sensed) -> np.ndarray:
        """The inverse of the holder's pose at the reading's instant: a holder at rest gives the
        same bytes cycle after cycle, so a new pose only is inverted (the same bits)."""
        T = np.asarray(T_global_hold6_sensed, float)
        key = T.tobytes()
        if key != self._sensed_inv_key:
            self._sensed_inv_key, self._sensed_inv = key, inv_homo(T)
        return self._sensed_inv

    def halt(self, reason: str, detail: str) -> TrackingStop:
        """Stop from outside a cycle (an arm fault seen by the shell): every later :meth:`step`
        returns no command.  The first stop stays; returns the stop in force."""
        if self.s.stop is None:
            self.s.stop = TrackingStop(reason, detail, self.s.travel_mm, self.s.cycle)
        return self.s.stop

    def _stop(self, cycle: int, reason: str, detail: str) -> CycleOutput:
        self.s.stop = TrackingStop(reason, detail, self.s.travel_mm, cycle)
        return self._stopped_output(cycle)

    def _stopped_output(self, cycle: int) -> CycleOutput:
        s = self.s
        return CycleOutput(cycle=cycle, tool_cmd=None, hold_cmd=None, stop=s.stop, phase=PHASE_TRACKING,
                           travel_mm=s.travel_mm, yaw_rad=0.0, pitch_rad=0.0, reading=INVALID_READING,
                           delay_state=DELAY_OFF, tcp_idx=s.tcp_idx, queue_len=len(s.seam_pos))


def _seam_transform(reading: Reading) -> np.ndarray:
    """``sensor T seam`` of a reading: Trans(x, y, 0) Rz(roll) (identity when invalid, §6.2.5)."""
    t = np.eye(4)
    if not reading.valid:
        return t
    c, s = math.cos(reading.roll_rad), math.sin(reading.roll_rad)
    t[0, 0], t[0, 1], t[1, 0], t[1, 1] = c, -s, s, c
    t[0, 3], t[1, 3] = reading.x_mm, reading.y_mm
    return t
