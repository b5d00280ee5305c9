"""Plus mode: a seam-map tracker that holds its speed and its seam (issue 12 item 4).

Not the thesis's algorithm (that is ``thesis``/``listing``, droid.tasks.seam.core);
it keeps the thesis's frames (eq. 5.1-5.5, 5.10-5.11: the seam in the holder's
wrist frame, the command through the holder's pose) and replaces the patch by a
seam map (droid.tasks.seam.seammap).  Per 30 Hz cycle:

1. the tool point in the holder's wrist frame from the Status poses (eq. 5.5,
   5.10) -- the holder's pose is read every cycle, so a moving holder moves
   the map with it;
2. the lead reading, after the transport-delay buffer of §6.2.5, is placed
   with the Reis and GMF1 poses *of its own capture instant*
   (``locate``: droid.tasks.seam.cycle) and enters the map.  A delayed or
   late reading lands where it was taken, so transport delay cannot feed
   back into the loop (immune by construction); the delay buffer's zero data
   carry no capture instant and are not measurements: skipped;
3. the commanded arc length ``s_cmd`` advances at the commanded travel speed
   -- from rest with the acceleration limit ``SeamParams.accel_mm_s2`` --
   independent of where the arm is: the tool is *told* to be at the map's
   point of ``s_cmd`` each cycle (feed-forward of the seam's position,
   direction and curvature through the map's local fit), so the achieved
   speed is the commanded one once the arm follows;
4. the tool frame: x (the tool axis) along the map's surface normal at
   ``s_cmd`` (normal to the surface, with its roll); z in the surface's
   tangent plane, toward the map point one CAMERA_TO_TCP chord ahead, so the
   lead sensor turns about the tool axis as the seam curves and its laser
   line stays on the seam (on a straight seam that is the seam tangent at the
   tool point);
5. integral action on depth: the measured tool point's depth from the map
   (along the normal, at the tool's own arc length) is integrated and taken
   off the command, which removes a steady depth error of the arm;
6. stops: the run length reached (end of seam), the lead sensor invalid for
   more than ``lost_cycles`` cycles or ``s_cmd`` beyond the map's bridged gap
   (seam lost), an unreachable command, a runaway, an arm fault (:meth:`PlusTracker.halt`;
   as the thesis modes).
"""
from __future__ import annotations

import math

import numpy as np

from droid.kinematics import RobotModel, Unreachable
from droid.kinematics.transforms import inv_homo
from droid.tasks.seam.core import CycleOutput, _seam_transform, mount
from droid.tasks.seam.guard import TravelGuard
from droid.tasks.seam.ik import hinted_ik
from droid.tasks.seam.params import PHASE_DEAD_ZONE, PHASE_INITIAL, PHASE_TRACKING, SeamParams
from droid.tasks.seam.stops import STOP_LOST, STOP_UNREACHABLE, TrackingStop
from droid.tasks.seam.compliance import StaticDeflection
from droid.tasks.seam.delay import DELAY_OFF, INVALID_READING, Reading
from droid.tasks.seam.seammap import SeamMap, chord_point

#: Integral gain on the tool's depth error [1/cycle] (time constant ~0.7 s at 30 Hz).
DEPTH_KI = 0.05
#: Largest depth correction the integrator may apply [mm].
DEPTH_LIMIT_MM = 3.0
#: Half-width of the window the tool's surface normal (the roll) is averaged over [mm].
NORMAL_HALF_MM = 20.0
#: The commanded point comes from the map's fit over this many times its window.
POSITION_WIDE = 2.0
#: The tool frame's tangent comes from the map's fit over this many times its window (±18 mm).
ORIENT_WIDE = 3.0
#: Alpha-beta filter of the sensor's aim about the tool axis (per cycle): angle and turn-rate gains.
AIM_ALPHA = 0.6
AIM_BETA = 0.1
#: Largest turn of the sensor's aim about the tool axis in one cycle [rad] (90 deg/s at 30 Hz).
AIM_RATE_RAD = math.radians(3.0)


class PlusTracker:
    """The plus-mode core; the same ``step`` interface as :class:`SeamTracker` (see the module docstring)."""

    def __init__(self, params: SeamParams, T_wcp_tool, T_wcp_sensor, tool_model: RobotModel | None = None):
        mount(self, params, T_wcp_tool, T_wcp_sensor, tool_model)
        self.map = SeamMap(gap_mm=params.gap_mm)
        self.cycle = 0
        self.s_cmd = 0.0  # commanded arc length along the map [mm]
        self.v = 0.0  # commanded travel speed now [mm/s]
        self.s_tool = 0.0  # the measured tool's arc length [mm]
        self.depth_bias_mm = 0.0
        self.invalid_run = 0
        self.q_prev = None
        self.hold_cmd = None
        self.stop: TrackingStop | None = None
        self.travel = TravelGuard(params)
        self.used_readings = 0
        self.z_aim: np.ndarray | None = None  # the smoothed travel axis (the sensor's aim), holder frame
        self.aim_rate = 0.0  # its turn about the tool axis per cycle [rad]
        self.defl = None  # the drives' static deflection (params.compliance and a robot file with [dynamics])
        if params.compliance and tool_model is not None:
            d = StaticDeflection(tool_model)
            self.defl = d if d.active else None

    @property
    def stopped(self) -> TrackingStop | None:
        return self.stop

    @property
    def travel_mm(self) -> float:
        """Tool travel since the start [mm]."""
        return self.travel.travel_mm

    def halt(self, reason: str, detail: str) -> TrackingStop:
        """As :meth:`SeamTracker.halt`: stop from outside a cycle; the first stop stays."""
        if self.stop is None:
            self.stop = TrackingStop(reason, detail, self.travel_mm, self.cycle)
        return self.stop

    def _stop(self, cycle: int, reason: str, detail: str) -> CycleOutput:
        self.stop = TrackingStop(reason, detail, self.travel_mm, cycle)
        return self._stopped_output(cycle)

    def _stopped_output(self, cycle: int) -> CycleOutput:
        return CycleOutput(cycle=cycle, tool_cmd=None, hold_cmd=None, stop=self.stop, phase=PHASE_TRACKING,
                           travel_mm=self.travel_mm, yaw_rad=0.0, pitch_rad=0.0, reading=INVALID_READING,
                           delay_state=DELAY_OFF, tcp_idx=0, queue_len=self.map.size)

    def _link_pose(self, T_status) -> np.ndarray:
        """The Reis wrist-centre pose of its links: a Status pose (motor-side encoders) corrected
        for the drives' static deflection (droid.tasks.seam.compliance); unchanged without it."""
        T = np.asarray(T_status, float)
        if self.defl is None:
            return T
        try:
            q_m = hinted_ik(self.tool_model, T, self.q_prev)
        except (Unreachable, ValueError):
            return T
        return self.tool_model.fk(self.defl.link_deg(q_m))

    def _smooth_aim(self, z: np.ndarray, x: np.ndarray) -> np.ndarray:
        """The travel axis toward the sensor's aim point ``z``, smoothed in the plane normal to
        ``x``: an alpha-beta filter of its angle (AIM_ALPHA, AIM_BETA a cycle) -- it follows a
        steadily turning aim (an arc) without a steady lag, and does not pass on the jitter of the
        map's front, where each new knot moves the fit; a wrist that chased that would shake the
        arm (docs/seamtrack.md, "On the full arm") -- and turns at most AIM_RATE_RAD a cycle."""
        if self.z_aim is None:
            self.z_aim, self.aim_rate = z, 0.0
            return z
        prev = self.z_aim - x * float(self.z_aim @ x)
        prev = prev / max(float(np.linalg.norm(prev)), 1e-12)
        ang = math.atan2(float(np.cross(prev, z) @ x), float(prev @ z))  # from the last aim
        resid = ang - self.aim_rate
        step = max(-AIM_RATE_RAD, min(AIM_RATE_RAD, self.aim_rate + AIM_ALPHA * resid))
        self.aim_rate = max(-AIM_RATE_RAD, min(AIM_RATE_RAD, self.aim_rate + AIM_BETA * resid))
        out = prev * math.cos(step) + np.cross(x, prev) * math.sin(step)
        self.z_aim = out
        return out

    def step(self, T_global_hold6, T_global_tool6, reading: Reading, q_tool_deg=None, elapsed_cycles: float = 1.0,
             T_global_tool6_sensed=None, T_global_hold6_sensed=None, locate=None) -> CycleOutput:
        """One 30 Hz cycle (see the module docstring); ``locate(reading)`` gives the (Reis, GMF1)
        global poses of the reading's capture instant or None (dropped); without it the sensed
        poses passed (or the current ones) are used."""
        cycle = self.cycle
        self.cycle += 1
        if self.stop is not None:
            return self._stopped_output(cycle)
        T_hold = np.asarray(T_global_hold6, float)
        hold_inv = inv_homo(T_hold)
        T_global_tool6 = self._link_pose(T_global_tool6)
        T_tool_H = hold_inv @ np.asarray(T_global_tool6, float) @ self.T67tool  # eq. 5.10, 5.5
        tool = T_tool_H[:3, 3].copy()
        in_dead_zone = cycle < self.p.dead_zone_cycles
        if self.map.size == 0:  # the initial straight section: from the tool's start point (§6.1.1)
            self.map.seed(tool, T_tool_H[:3, 0], T_tool_H[:3, 2])
            self.T_start_H = T_tool_H.copy()
            self.hold_cmd = T_hold.copy()
        # the run's progress: the arc length of the measured tool's foot on the seam map
        self.s_tool = self.map.project(tool, self.s_tool)
        stop = self.travel.step(tool, elapsed_cycles, guard_runaway=not in_dead_zone, progress_mm=self.s_tool)
        if stop:
            return self._stop(cycle, *stop)
        if self.q_prev is None and q_tool_deg is not None:
            self.q_prev = np.asarray(q_tool_deg, float)

        used, delay_state = self._map_reading(reading, locate, T_global_tool6, hold_inv,
                                              (T_global_tool6_sensed, T_global_hold6_sensed))
        if not used.zeroed and not in_dead_zone:
            self.invalid_run = 0 if used.valid else self.invalid_run + 1
            if self.invalid_run > self.p.lost_cycles:
                return self._stop(cycle, STOP_LOST, f"lead sensor invalid for {self.invalid_run} cycles")
        f = self._travel()
        if f is None:
            return self._stop(cycle, STOP_LOST, f"no seam mapped within {self.p.gap_mm:g} mm ahead of the tool "
                                                f"(map ends at {self.map.front_s:.1f} mm)")
        self._depth_integral(tool, in_dead_zone)
        T_target, aim_rad = self._tool_frame(f)
        tool_cmd = T_hold @ T_target @ self.T67tool_inv  # eq. 5.11
        try:
            q = hinted_ik(self.tool_model, tool_cmd, self.q_prev)
        except (Unreachable, ValueError) as exc:
            return self._stop(cycle, STOP_UNREACHABLE, str(exc))
        if q is not None:
            if self.defl is not None:  # the motor angles that put the deflected links there
                q = self.defl.motor_deg(q)
                tool_cmd = self.tool_model.fk(q)
            self.q_prev = q
        first = self.map.first_reading_s
        phase = PHASE_DEAD_ZONE if in_dead_zone else (
            PHASE_TRACKING if first is not None and self.s_cmd >= first else PHASE_INITIAL)
        return CycleOutput(cycle=cycle, tool_cmd=tool_cmd, hold_cmd=self.hold_cmd, stop=None, phase=phase,
                           travel_mm=self.travel_mm, yaw_rad=aim_rad, pitch_rad=0.0, reading=used,
                           delay_state=delay_state, tcp_idx=0, queue_len=self.map.size, q_tool_deg=q)

    def _map_reading(self, reading: Reading, locate, T_global_tool6, hold_inv, sensed):
        """The reading, placed where it was taken: through the transport delay, then (when valid
        and its capture poses are known) its seam point and tangent added to the map (eq. 5.1/5.3).
        Returns the reading used and the delay's state."""
        if not reading.valid:
            reading = INVALID_READING
        used, delay_state = self.delay.filter(reading, self.travel_mm)
        if not used.zeroed and used.valid:
            located = locate(used) if locate is not None else sensed
            if located is not None:
                tool_s = T_global_tool6 if located[0] is None else self._link_pose(located[0])
                hold_s_inv = hold_inv if located[1] is None else inv_homo(np.asarray(located[1], float))
                frame = hold_s_inv @ tool_s @ self.Tcamera_6 @ _seam_transform(used)  # eq. 5.1/5.3
                self.map.add(frame[:3, 3], frame[:3, 0])
                self.used_readings += 1
        return used, delay_state

    def _travel(self):
        """Travel: the commanded speed, from rest with the acceleration limit; the map's fit at the
        next commanded arc length (None: no seam mapped there; the arc length stays)."""
        dt = 1.0 / self.p.cycle_hz
        if self.map.first_reading_s is not None:  # nothing sensed yet: stand at the start
            self.v = min(self.p.speed_mm_s, self.v + self.p.accel_mm_s2 * dt)
        s_next = self.s_cmd + self.v * dt
        f = self.map.fit(s_next, wide=POSITION_WIDE) if s_next <= self.map.front_s else self.map.fit(s_next)
        if f is not None:
            self.s_cmd = s_next
        return f

    def _depth_integral(self, tool: np.ndarray, in_dead_zone: bool) -> None:
        """Integral action on depth: the measured tool against the map (not in the dead zone)."""
        ft = self.map.fit(self.s_tool)
        if ft is not None and not in_dead_zone:
            e_depth = float((tool - ft.p) @ ft.n)  # + : the tool is below the seam (into the surface)
            self.depth_bias_mm = float(np.clip(self.depth_bias_mm + DEPTH_KI * e_depth, -DEPTH_LIMIT_MM,
                                               DEPTH_LIMIT_MM))

    def _tool_frame(self, f) -> tuple[np.ndarray, float]:
        """The tool frame in the holder's frame: normal to the surface, the sensor aimed at the
        seam ahead; and the aim's angle from the seam's tangent [rad]."""
        fo = self.map.fit(f.s_mm, wide=ORIENT_WIDE) or f  # the frame from a wider fit: no jitter of the knots
        x = self.map.normal(f.s_mm, NORMAL_HALF_MM, fo.t)
        t = fo.t - x * float(fo.t @ x)
        t = t / max(float(np.linalg.norm(t)), 1e-12)
        # where no chord of CAMERA_TO_TCP reaches the map (the end of a tight arc: the map and its
        # extrapolation bend back toward the tool), aim at the farthest mapped seam, never along
        # the tool's tangent (docs/seamtrack.md, "The R25 arc")
        ahead = chord_point(self.map, f.s_mm, f.p, self.camera_to_tcp_mm, farthest=True)
        z = (ahead.p - f.p) if ahead is not None else t
        z = z - x * float(z @ x)
        z = z / max(float(np.linalg.norm(z)), 1e-12)
        z = self._smooth_aim(z, x)
        y = np.cross(z, x)
        T_target = np.eye(4)
        T_target[:3, 0], T_target[:3, 1], T_target[:3, 2] = x, y, z
        T_target[:3, 3] = f.p - self.depth_bias_mm * x
        aim_rad = math.atan2(float(np.cross(t, z) @ x), float(t @ z))
        return T_target, aim_rad
