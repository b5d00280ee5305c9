"""One seam-tracking cycle for real time and lockstep (issue 12 item 1; thesis §5.5, Figure 5.9).

Everything the seam-tracking program does around the core, apart from I/O,
lives here and is called unchanged by ``droid-seamtrack`` (the real-time
shell, droid/tasks/seamtrack.py) and by the lockstep trial
(droid/experiments/trial.py):

* **cycle counting** from the cell's ``heartbeat_hz``: one 30 Hz tracking
  cycle every ``heartbeat_hz / 30`` ticks, one 10 Hz log row every
  ``heartbeat_hz / 10`` ticks (§6.1).  A heartbeat that is not a whole
  multiple of the two rates cannot serve them: :func:`cycle_ticks_for`
  refuses it (``ValueError``; the shells turn it into exit 2) rather than
  running at another rate than the one the gains and the speed assume;
* **the pose histories**: the Reis and the GMF1 Status poses of every tick,
  stored under their Status's own tick (:class:`PoseHistory`);
* **associating a reading with a pose**: a lead reading that reached the
  Status at tick m was taken at ``m - SENSOR_LAG_TICKS`` (or at its own
  capture stamp, when the sensor line carries one); a Status pose of tick n
  shows the arm at ``n - STATUS_AGE_TICKS``.  The reading is placed with both
  robots' poses interpolated at its capture instant (eq. 5.3 places the
  reading with the camera pose of its own instant).  A reading whose instant
  lies outside the history, or in the future, is dropped and counted
  (``TrackingCycle.dropped``);
* **elapsed cycles** between two Status poses (a late Status spans more than
  one cycle: the runaway guard scales with it);
* **the tool-tip sensor's readings** (issue 12 item 2, §6.1's measuring
  sensor) placed the same way: :meth:`TrackingCycle.place_tool` gives a
  reading's capture instant (its stamp, else its Status tick minus the lag),
  both robots' poses then, the tool's travel then (from the cycles' travel,
  each stored under the instant its Status pose shows) and the measured seam
  point in the holder's wrist-centre frame; a reading whose instant lies in
  the future or before the history is dropped and counted
  (``TrackingCycle.tool_dropped``).  The tool-tip sensor only measures:
  nothing of it reaches the core;
* **the fault rule** (issue 16; an addition): before each cycle the shell hands
  :meth:`TrackingCycle.check_faults` the ``fault`` field of both arms' Status
  (the Reis and the GMF1).  An arm with a fault it cannot move with
  (``FAULTS_CANNOT_MOVE``: servo, watchdog -- the amplifiers latched off --, device), or
  one that a protective stop interrupted (FAULT_BRAKING: the servo ran out of way-points and
  braked; FAULT_COLLISION: the guard's stop; together ``FAULTS_STOP_RUN``),
  stops the run at once as ``fault``, the detail naming the arm and every fault bit
  it shows (:func:`arm_faults`: ``arm1 faults: servo, braking``), and no command
  is written after it.  The thesis's tracker has no such rule -- it runs until
  "some kind of user intervention" stops it (§5.5.1) -- but a latched watchdog
  fault means "no further motion is possible without resetting the power"
  (§2.3, §4.1.2), and a task only reads the Status and writes the Command
  (§3.4): commanding such an arm on would only wait for a stall.  A protective
  stop leaves an arm that could follow again at the next command, but the weld
  slowed or stopped where it braked (a defect: the tool lags the seam by what it
  braked), so the run says so and ends rather than ride through it (issue 40
  item 4; the start moves before the run do ride through, droid.tasks.resume);
* the core: :class:`droid.tasks.seam.core.SeamTracker` (modes ``thesis`` and
  ``listing``) or :class:`droid.tasks.seam.plus.PlusTracker` (mode ``plus``).
"""
from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, replace
import numpy as np

from droid.brain.db.layouts import FAULTS_STOP_RUN, fault_names
from droid.brain.plumbing.sensor_line import seam_transform
from droid.kinematics.transforms import EYE4
from droid.tasks.seam.core import CycleOutput, SeamTracker
from droid.tasks.seam.params import MODE_PLUS, SeamParams
from droid.tasks.seam.stops import STOP_FAULT, TrackingStop
from droid.tasks.seam.delay import INVALID_READING, Reading

_EYE3 = np.eye(3)

#: The 10 Hz log of §6.1 [Hz].
LOG_HZ = 10.0
#: A lead reading that reaches the Brain's Status at tick m left the camera about a tick
#: earlier (the MVS program, 20 characters at 19200 baud, the remote's tick; docs/mvs.md).
SENSOR_LAG_TICKS = 1
#: The Reis Status of tick n holds the servo's 125 Hz encoder sample before n - 1/2 tick
#: (the servo agent copies it half a tick before the heartbeat, docs/reis.md): on average
#: the arm at n - 0.5 tick - 4 ms, 0.74 tick at 60 Hz.
STATUS_AGE_TICKS = 0.75
#: Pose history [ticks]: a 16-cycle transport delay plus an 8-cycle constant latency and margin.
POSE_HISTORY_TICKS = 128


def stamped(reading: Reading, stamp_tick: float) -> Reading:
    """``reading`` with its capture instant ``stamp_tick`` [ticks]: ``dataclasses.replace``'s
    result, made directly for a plain Reading (a tracking cycle's every reading)."""
    if type(reading) is Reading:
        return Reading(reading.x_mm, reading.y_mm, reading.roll_rad, reading.valid, reading.zeroed, stamp_tick)
    return replace(reading, stamp_tick=stamp_tick)


def cycle_ticks_for(heartbeat_hz: float, rate_hz: float) -> int:
    """Heartbeat ticks per period of ``rate_hz``; refuses a heartbeat that cannot serve it."""
    if not (isinstance(heartbeat_hz, (int, float)) and math.isfinite(heartbeat_hz) and heartbeat_hz > 0):
        raise ValueError(f"heartbeat must be a positive rate, got {heartbeat_hz!r} Hz")
    ratio = heartbeat_hz / rate_hz
    n = int(round(ratio))
    if n < 1 or abs(ratio - n) > 1e-6 * max(1.0, ratio):
        raise ValueError(f"a heartbeat of {heartbeat_hz:g} Hz cannot serve the {rate_hz:g} Hz seam-tracking "
                         f"rate (it must be a whole multiple of {rate_hz:g} Hz, e.g. 60 Hz)")
    return n


def arm_faults(arms) -> str | None:
    """The fault rule of the tracker (see the module docstring), for both shells.

    ``arms``: (subunit name, Status ``fault`` bits) of each arm the tracker drives.  None when
    every arm can move; else the stop detail naming each faulted arm and all of its fault bits
    (droid.brain.db.layouts.fault_names), e.g. ``arm1 faults: servo, braking``; two arms are
    joined with ``; ``.  An arm stops the run when a bit of ``FAULTS_STOP_RUN`` is set (a fault
    it cannot move with, or a protective stop: braking, collision)."""
    parts = [f"{name} faults: {', '.join(fault_names(bits))}" for name, bits in arms
             if int(bits) & FAULTS_STOP_RUN]
    return "; ".join(parts) if parts else None


def _rot_log(R: np.ndarray) -> np.ndarray:
    """Rotation vector of a rotation matrix [rad]."""
    c = max(-1.0, min(1.0, (float(R.trace()) - 1.0) / 2.0))  # what np.trace(R) calls
    a = math.acos(c)
    (r00, r01, r02), (r10, r11, r12), (r20, r21, r22) = R.tolist()  # plain floats: the same differences
    w = np.array([r21 - r12, r02 - r20, r10 - r01])
    if a < 1e-9:
        return w / 2.0
    return w * (a / (2.0 * math.sin(a)))


def _rot_exp(v: np.ndarray) -> np.ndarray:
    a = math.sqrt(float(v.dot(v)))  # np.linalg.norm(v), without its overhead
    if a < 1e-12:
        return _EYE3.copy()
    k0, k1, k2 = (v / a).tolist()
    K = np.array([[0.0, -k2, k1], [k2, 0.0, -k0], [-k1, k0, 0.0]])
    return _EYE3 + math.sin(a) * K + (1.0 - math.cos(a)) * (K @ K)


def interpolate_pose(T0: np.ndarray, T1: np.ndarray, u: float) -> np.ndarray:
    """The pose a fraction ``u`` (0..1) of the way from ``T0`` to ``T1`` (translation linear,
    rotation along the geodesic)."""
    out = EYE4.copy()
    out[:3, 3] = T0[:3, 3] + u * (T1[:3, 3] - T0[:3, 3])
    out[:3, :3] = T0[:3, :3] @ _rot_exp(u * _rot_log(T0[:3, :3].T @ T1[:3, :3]))
    return out


class PoseHistory:
    """Poses stamped with their time [ticks, may be fractional], oldest first, ``span`` ticks kept.

    :meth:`at` interpolates between neighbours with :attr:`interpolate` (:func:`interpolate_pose`;
    an experiment may put a compiled one of the same bits here: droid.experiments.seam_kernel)."""

    interpolate = staticmethod(interpolate_pose)

    def __init__(self, span_ticks: float = POSE_HISTORY_TICKS) -> None:
        self.span = float(span_ticks)
        self._items: deque[tuple[float, np.ndarray]] = deque()

    def __len__(self) -> int:
        return len(self._items)

    def add(self, t: float, T) -> None:
        """Remember ``T`` at time ``t``; a time not after the newest replaces nothing (ignored)."""
        t = float(t)
        if self._items and t <= self._items[-1][0]:
            return
        self._items.append((t, np.asarray(T, float).copy()))
        while self._items and self._items[0][0] < t - self.span:
            self._items.popleft()

    @property
    def newest(self) -> tuple[float, np.ndarray] | None:
        return self._items[-1] if self._items else None

    def at(self, t: float) -> np.ndarray | None:
        """The pose at time ``t``, interpolated between its neighbours; None when ``t`` lies
        before the oldest or after the newest entry (no extrapolation)."""
        items = self._items
        if not items or t < items[0][0] or t > items[-1][0]:
            return None
        for i in range(len(items) - 1, -1, -1):
            ti, Ti = items[i]
            if ti <= t:
                if ti == t or i == len(items) - 1:
                    return Ti.copy()
                tj, Tj = items[i + 1]
                return self.interpolate(Ti, Tj, (t - ti) / (tj - ti))
        return None


class ValueHistory:
    """Numbers stamped with their time [ticks], oldest first, ``span`` ticks kept; read linearly
    interpolated, held at the ends (NaN while empty)."""

    def __init__(self, span_ticks: float = POSE_HISTORY_TICKS) -> None:
        self.span = float(span_ticks)
        self._t: deque[float] = deque()
        self._v: deque[float] = deque()

    def __len__(self) -> int:
        return len(self._t)

    def add(self, t: float, v: float) -> None:
        t = float(t)
        if self._t and t <= self._t[-1]:
            return
        self._t.append(t)
        self._v.append(float(v))
        while self._t and self._t[0] < t - self.span:
            self._t.popleft()
            self._v.popleft()

    def at(self, t: float) -> float:
        if not self._t:
            return math.nan
        return float(np.interp(t, self._t, self._v))


@dataclass(frozen=True)
class PlacedTool:
    """A tool-tip reading at its capture instant ``tick`` [ticks]: both robots' poses then
    (global 4x4 [mm]), the tool's travel then [mm] (NaN before the first cycle), and the
    measured seam point in the holder's wrist-centre frame [mm]."""

    tick: float
    T_global_tool6: np.ndarray
    T_global_hold6: np.ndarray
    travel_mm: float
    seam_in_hold_mm: np.ndarray


class TrackingCycle:
    """The tracking cycle of both shells (see the module docstring).

    Per heartbeat tick the shell calls :meth:`remember` with the Status poses
    (and their Status ticks); when :meth:`due` says so it calls :meth:`step`
    and writes the command it returns for ``cycle_ticks`` ticks; when
    :meth:`log_due` says so it logs a row.
    """

    def __init__(self, params: SeamParams, T_wcp_tool, T_wcp_sensor, tool_model=None,
                 heartbeat_hz: float = 60.0, sensor_lag_ticks: float = SENSOR_LAG_TICKS,
                 status_age_ticks: float = STATUS_AGE_TICKS) -> None:
        self.heartbeat_hz = float(heartbeat_hz)
        self.cycle_ticks = cycle_ticks_for(heartbeat_hz, params.cycle_hz)
        self.log_ticks = cycle_ticks_for(heartbeat_hz, LOG_HZ)
        self.params = params
        self.sensor_lag_ticks = float(sensor_lag_ticks)
        self.status_age_ticks = float(status_age_ticks)
        if params.mode == MODE_PLUS:
            from droid.tasks.seam.plus import PlusTracker

            self.core = PlusTracker(params, T_wcp_tool, T_wcp_sensor, tool_model)
        else:
            self.core = SeamTracker(params, T_wcp_tool, T_wcp_sensor, tool_model)
        self.tool_poses = PoseHistory()
        self.hold_poses = PoseHistory()
        self.dropped = 0  # readings whose instant lies outside the pose history (or in the future)
        self.tool_dropped = 0  # tool-tip readings likewise (place_tool)
        self.travel = ValueHistory()  # the tool's travel [mm] at the instants the cycles saw
        self._tool_inv_key, self._tool_inv = None, None  # place_tool's holder pose (bytes) and its inverse
        self._next_cycle: int | None = None
        self._next_log: int | None = None
        self._status_tick: int | None = None
        self.last: CycleOutput | None = None

    @property
    def camera_to_tcp_mm(self) -> float:
        return self.core.camera_to_tcp_mm

    @property
    def stopped(self):
        return self.core.stopped

    # -- counting ------------------------------------------------------------
    def due(self, tick: int) -> bool:
        """A tracking cycle runs at this tick (the first tick asked, then every ``cycle_ticks``;
        a late wake-up that skipped ticks still steps once)."""
        if self._next_cycle is None or tick >= self._next_cycle:
            self._next_cycle = tick + self.cycle_ticks
            return True
        return False

    def log_due(self, tick: int) -> bool:
        """A 10 Hz log row is due at this tick (the first ``log_ticks - 1`` ticks after the first ask)."""
        if self._next_log is None:
            self._next_log = tick + self.log_ticks - 1
        if tick >= self._next_log:
            self._next_log = tick + self.log_ticks
            return True
        return False

    # -- the pose histories ----------------------------------------------------
    def remember(self, tool_tick: int, T_global_tool6, hold_tick: int | None = None, T_global_hold6=None) -> None:
        """Keep the Reis (and GMF1) Status poses under the times they show the arm at."""
        self.tool_poses.add(tool_tick - self.status_age_ticks, T_global_tool6)
        if T_global_hold6 is not None:
            self.hold_poses.add((tool_tick if hold_tick is None else hold_tick) - self.status_age_ticks,
                                T_global_hold6)

    def capture_tick(self, status_tick: int, stamp_tick: float | None = None) -> float:
        """The instant a reading was taken [ticks]: its own stamp, else its Status tick - the lag."""
        return float(stamp_tick) if stamp_tick is not None else status_tick - self.sensor_lag_ticks

    def locate(self, reading: Reading):
        """Both robots' poses (Reis, GMF1; global 4x4) at the instant ``reading.stamp_tick``,
        or None -- the reading dropped and counted -- when that instant lies in the future or
        before the history.  A GMF1 without a history: None in its place (the current pose)."""
        t_c = reading.stamp_tick
        if t_c is None or not len(self.tool_poses):
            return (None, None)
        sensed = self.tool_poses.at(t_c)
        newest_t, newest_T = self.tool_poses.newest
        if sensed is None and newest_t < t_c <= newest_t + self.status_age_ticks + 0.5:
            sensed = newest_T  # newer than the newest Status shows: the newest pose
        if sensed is None:
            self.dropped += 1
            return None
        hold = None
        if len(self.hold_poses):
            hold = self.hold_poses.at(t_c)
            if hold is None:
                hold = self.hold_poses.newest[1]
        return sensed, hold

    # -- one cycle -------------------------------------------------------------
    def check_faults(self, arms) -> TrackingStop | None:
        """Before a cycle: ``arms`` = (subunit name, Status ``fault`` bits) of the Reis and the
        GMF1.  When :func:`arm_faults` finds a fault, the core stops (``fault``, its detail) and
        the stop is returned -- the shell writes no command; every later :meth:`step` returns
        none.  None: every arm can move (the cycle goes on)."""
        detail = arm_faults(arms)
        if detail is None:
            return None
        return self.core.halt(STOP_FAULT, detail)

    def step(self, T_global_hold6, T_global_tool6, tool_tick: int, reading: Reading, reading_status_tick: int,
             q_tool_deg=None) -> CycleOutput:
        """One tracking cycle: the reading placed with the poses of its instant, the core stepped."""
        elapsed = 1.0 if self._status_tick is None else max(1.0, (tool_tick - self._status_tick) / self.cycle_ticks)
        self._status_tick = tool_tick
        sensed = sensed_hold = None
        if reading.valid:
            reading = stamped(reading, self.capture_tick(reading_status_tick, reading.stamp_tick))
            if self.params.mode != MODE_PLUS:  # the thesis's cores place the fresh reading now
                located = self.locate(reading)
                if located is None:
                    reading = INVALID_READING
                else:
                    sensed, sensed_hold = located
        out = self.core.step(T_global_hold6, T_global_tool6, reading, q_tool_deg, elapsed_cycles=elapsed,
                             T_global_tool6_sensed=sensed, T_global_hold6_sensed=sensed_hold,
                             **({"locate": self.locate} if self.params.mode == MODE_PLUS else {}))
        self.last = out
        self.travel.add(tool_tick - self.status_age_ticks, out.travel_mm)
        return out

    # -- the tool-tip sensor (measuring only) ------------------------------------
    def place_tool(self, reading: Reading, status_tick: int, T_wcp_tool) -> "PlacedTool | None":
        """A tool-tip reading (x height, y lateral [mm], roll [rad]; its own ``stamp_tick`` or None)
        that reached its Status at ``status_tick``, placed at its capture instant; None when it is
        invalid, or -- dropped and counted in ``tool_dropped`` -- when its instant lies in the
        future or before the pose history."""
        if not reading.valid:
            return None
        t_c = self.capture_tick(status_tick, reading.stamp_tick)
        T_tool = self.tool_poses.at(t_c)
        if T_tool is None and len(self.tool_poses):
            newest_t, newest_T = self.tool_poses.newest
            if newest_t < t_c <= newest_t + self.status_age_ticks + 0.5:
                T_tool = newest_T  # newer than the newest Status shows: the newest pose
        if T_tool is None:
            self.tool_dropped += 1
            return None
        T_hold = self.hold_poses.at(t_c) if len(self.hold_poses) else None
        if T_hold is None:
            T_hold = self.hold_poses.newest[1] if len(self.hold_poses) else np.eye(4)
        key = T_hold.tobytes()  # the holder usually stands still: invert a new pose only (the same bits)
        if key != self._tool_inv_key:
            self._tool_inv_key, self._tool_inv = key, np.linalg.inv(T_hold)
        T_seam = self._tool_inv @ T_tool @ np.asarray(T_wcp_tool, float) @ seam_transform(
            reading.x_mm, reading.y_mm, reading.roll_rad)
        return PlacedTool(tick=t_c, T_global_tool6=T_tool, T_global_hold6=T_hold, travel_mm=self.travel.at(t_c),
                          seam_in_hold_mm=T_seam[:3, 3].copy())
