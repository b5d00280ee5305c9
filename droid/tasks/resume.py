"""A task's positioning move rides through a protective stop (issue 40 item 4).

A protective stop: the arm's servo ran out of way-points and braked -- the Status shows
FAULT_BRAKING, "the servo ran out of commands and braked", e.g. after a host stall starved
the servo agent (docs/safety.md) -- and the planner cancelled the move in progress
(``cmd_result = CMD_FAILED``; its log: "cancelled command N: faults: braking").  Nothing is
broken: once the planner re-anchored where the arm stopped, the servo agent sends way-points
again and the bit clears (droid/subunits/reis/servo_agent.py; on the ABB, droid-egm sets it
for the one period it refused a way-point too far from its target; the GMF1's programs never
set it).  So the task re-issues the move toward the same target from where the arm stands
(thesis §3.4: a task only writes the Command record), at most :data:`MAX_RESUMES` times.

Every other fault bit -- servo, watchdog, limit, force, device, link, heartbeat, and any bit
a later layout adds (a collision) -- is *hard*: a failed move that saw one is not resumed.

Pure: the decisions and the words, no records, no clock.  :meth:`droid.tasks.arm.BrainArm.move`
runs them against the Brain's Status and Command records.

* **Where the arm is along the move** (:func:`progress`): by joint-space distance, the
  arm's joint angles [deg] projected onto the straight line in joint space from the move's
  start to its target -- the line the planner's way-points follow (a joint command
  interpolates counts linearly; a cartesian one is resolved to a joint target first,
  droid/arm/planner.py) -- as a fraction of the line's length, clamped to [0, 1].
  Measured where the arm came to rest, always against the first move of the task (its
  start and its target), so a second stop says how far along the whole move it was.
* **The resumed move's duration** (:func:`resumed_seconds`): the remaining joint-space
  distance at the original move's average joint-space speed (Euclidean over the six joints
  [deg/s]), never shorter than the joints' speed limits allow, in whole heartbeat ticks
  rounded up -- so never faster than the original move.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from droid.brain.db.layouts import CMD_FAILED, FAULT_BRAKING, FAULT_NAMES, fault_names

#: At most this many resumes of one move; a further protective stop fails it.
MAX_RESUMES = 3
#: The one fault bit a resume rides through.
RESUMABLE_FAULTS = FAULT_BRAKING
#: After a protective stop the arm must be at rest with FAULT_BRAKING clear within this [s].
REST_TIMEOUT_S = 5.0
#: At rest: this many Status records in a row, each of a newer heartbeat tick ...
REST_RECORDS = 3
#: ... whose encoders moved at most this much from the record before [counts] (the servo
#: holds to +-1 count; droid-seamtrack's settle rule uses 2).
REST_COUNTS = 2


def hard_faults(bits: int) -> int:
    """The fault bits of ``bits`` no resume rides through (every bit but FAULT_BRAKING)."""
    return int(bits) & ~RESUMABLE_FAULTS


def protective_stop(result: int, faults_seen: int) -> bool:
    """A move that ended with ``result`` (a CMD_* code) while the Status showed ``faults_seen``
    (every bit seen while it ran) was cancelled by a protective stop: it failed, braking
    was seen, and no hard fault was."""
    return int(result) == CMD_FAILED and bool(int(faults_seen) & FAULT_BRAKING) and not hard_faults(faults_seen)


def progress(q_start_deg, q_goal_deg, q_now_deg) -> float:
    """How far along the move from ``q_start_deg`` to ``q_goal_deg`` the arm at ``q_now_deg``
    is (joint angles [deg]): its projection onto the joint-space line between them as a
    fraction of the line's length, in [0, 1] (the module docstring).  A move of no length
    is done (1.0)."""
    a, b, q = (np.asarray(v, float) for v in (q_start_deg, q_goal_deg, q_now_deg))
    line = b - a
    length2 = float(line @ line)
    if length2 <= 0.0:
        return 1.0
    return min(1.0, max(0.0, float((q - a) @ line) / length2))


def resumed_seconds(q_start_deg, q_goal_deg, seconds: float, q_now_deg, q_goal_now_deg, vmax_deg_s,
                    max_s: float) -> float:
    """The resumed move's duration [s]: from ``q_now_deg`` to ``q_goal_now_deg`` (the target
    as resolved from here, [deg]) at the average joint-space speed of the original move
    (``q_start_deg`` -> ``q_goal_deg`` in ``seconds``), at least the time the joints' speed
    limits ``vmax_deg_s`` [deg/s] need, at most ``max_s``.  An original move of no length
    gives its own duration.  Round it up to whole ticks (:func:`resumed_ticks`)."""
    d0 = float(np.linalg.norm(np.asarray(q_goal_deg, float) - np.asarray(q_start_deg, float)))
    rest = np.asarray(q_goal_now_deg, float) - np.asarray(q_now_deg, float)
    dr = float(np.linalg.norm(rest))
    t = seconds * dr / d0 if d0 > 0.0 else float(seconds)
    t_limit = float(np.max(np.abs(rest) / np.asarray(vmax_deg_s, float)))
    return min(max(t, t_limit), float(max_s))


def resumed_ticks(seconds: float, heartbeat_hz: float) -> int:
    """``seconds`` [s] in whole heartbeat ticks, rounded up (never faster), at least one."""
    return max(1, math.ceil(seconds * float(heartbeat_hz) - 1e-9))


def resume_line(arm: str, fraction: float, faults_seen: int, n: int, of: int = MAX_RESUMES) -> str:
    """The stderr line of the ``n``-th resume (1-based) after a stop at ``fraction`` of the move."""
    why = ", ".join(fault_names(faults_seen)) or "braking"
    return (f"{arm}: protective stop at {round(100.0 * fraction):d} % of the move ({why}); "
            f"resuming from the arm's position ({n} of {of})")


def resumes_text(n: int) -> str:
    """``1 resume`` / ``2 resumes``."""
    return f"{n} resume{'' if n == 1 else 's'}"


def arrived_line(arm: str, n: int) -> str:
    """droid-move's stderr line after a move that needed ``n`` >= 1 resumes."""
    return f"{arm}: arrived after {resumes_text(n)}"


def summary_note(n: int) -> str:
    """What droid-seamtrack / droid-contact add to their summary line after ``n`` resumes of
    their start moves ("" when there were none)."""
    return f"; start moves: {resumes_text(n)} after a protective stop" if n else ""


@dataclass
class RestWatch:
    """Is the arm at rest with its braking fault clear?  Fed one Status record at a time
    (:meth:`at_rest`): True after :data:`REST_RECORDS` records in a row, each of a newer
    heartbeat tick, without FAULT_BRAKING, the encoders moving at most :data:`REST_COUNTS`
    from one to the next.  :meth:`hard` names a hard fault a record shows (the caller stops:
    no resume)."""

    records: int = REST_RECORDS
    tol_counts: int = REST_COUNTS
    _last_tick: int | None = None
    _last_pos: np.ndarray | None = None
    _still: int = 0

    @staticmethod
    def hard(fault_bits: int) -> str | None:
        """The names of ``fault_bits``' hard faults (``watchdog, servo``; a bit without a name as
        hex, ``0x1000``), None if there are none."""
        bits = hard_faults(fault_bits)
        if not bits:
            return None
        unnamed = bits & ~sum(FAULT_NAMES)
        return ", ".join(fault_names(bits) + ([f"{unnamed:#x}"] if unnamed else []))

    def at_rest(self, tick: int, encoder_pos_counts, fault_bits: int) -> bool:
        tick = int(tick)
        if self._last_tick is not None and tick <= self._last_tick:
            return self._still >= self.records  # the same record again: no news
        pos = np.asarray(encoder_pos_counts, np.int64)
        if int(fault_bits) & FAULT_BRAKING:
            self._still = 0
        elif self._last_pos is not None and int(np.max(np.abs(pos - self._last_pos))) <= self.tol_counts:
            self._still += 1
        else:
            self._still = 1  # the first record of a run: the next must agree with it
        self._last_tick, self._last_pos = tick, pos
        return self._still >= self.records


@dataclass
class Resumer:
    """The resume decisions of one move (the module docstring).

    ``q_start_deg`` / ``q_goal_deg``: the move's start and target [joint deg]; ``seconds``:
    its duration as planned (its ticks / the heartbeat rate); ``enabled``: False with
    ``--no-resume``.  :attr:`resumes` counts the resumes issued."""

    arm: str
    q_start_deg: np.ndarray
    q_goal_deg: np.ndarray
    seconds: float
    enabled: bool = True
    max_resumes: int = MAX_RESUMES
    resumes: int = 0

    def refusal(self, result: int, faults_seen: int) -> str | None:
        """After the move (or a resumed one) ended with ``result`` having seen ``faults_seen``:
        None when it is to be resumed; else "" when it was no protective stop (or resuming is
        off: the caller reports the failure as ever) or why a protective stop is not resumed
        (the resumes are used up)."""
        if not self.enabled or not protective_stop(result, faults_seen):
            return ""
        if self.resumes >= self.max_resumes:
            return (f"protective stop {self.resumes + 1} times, not resumed again "
                    f"(at most {self.max_resumes} resumes)")
        return None

    def fraction(self, q_now_deg) -> float:
        return progress(self.q_start_deg, self.q_goal_deg, q_now_deg)

    def next_line(self, q_now_deg, faults_seen: int) -> str:
        """Count a resume from ``q_now_deg`` and return its stderr line."""
        self.resumes += 1
        return resume_line(self.arm, self.fraction(q_now_deg), faults_seen, self.resumes, self.max_resumes)

    def seconds_from(self, q_now_deg, q_goal_now_deg, vmax_deg_s, max_s: float) -> float:
        return resumed_seconds(self.q_start_deg, self.q_goal_deg, self.seconds, q_now_deg, q_goal_now_deg,
                               vmax_deg_s, max_s)
