"""The workpiece holder of a trial: the GMF1 through its own controller and encoder path (issue 13 item 5).

Thesis §2.4, §4.2, §5.5: the GM Fanuc S400 holds the workpiece; DROID
commands it over the serial line to its KAREL server, reads its joints
through the encoder cards (droid-gmf1-encoder) and the seam tracker reads
the holder's pose from the GMF1's Status every cycle.  :class:`Gmf1Holder`
puts exactly that on a trial's scheduler
(:class:`droid.sim.gmf1.lockstep.Gmf1Lockstep`): the Fanuc twin -- the
KAREL controller at 9600 baud, its interpolated path, the arm of the robot
file's ``[dynamics]`` and ``[axis_servo]`` behind it
(:mod:`droid.arm.arm_dynamics`), the encoder cards -- and the GMF1
programs' cores (serial, encoder, the agent's command copy).

* :meth:`prepare` (before the trial's clock starts): home from the zero pose
  (the counters zeroed, as droid-home does) and move with a joint command to
  the holding pose of the trial's position; wait until DONE (the controller's
  in-position check) and let the Status settle.
* :meth:`drift` (the holder-moving trials): one cartesian MOVE of the wrist
  centre at a constant velocity [mm/s] for a given time, through KAREL (its
  ramps, its joint interpolation, its 6 Hz interpreter and its latency).
* :meth:`hold`: the tracker's one hold command at its first cycle
(gen_hold_robot_wcp: a MOVE to the pose the GMF1 has; not sent while it
drifts); :meth:`status_pose`: the pose the tracker reads (the encoder program's
  forward kinematics of the motor-side counts, global frame);
  :meth:`true_wcp`: the world's truth (the links, after the reducers' twist),
  which places the workpiece for the sensors.

The GMF1 is built by its package's lockstep builder (droid.sim.gmf1.lockstep.build, through the
registry: droid.sim.trial_cell.TrialCell.build_arms, the layout's holder_robot whose package
registers this ``holder`` model) from the trial's cell -- the built-in cell
(droid/cells/sim.toml) or ``TrialConfig.cell`` -- at the subunit its layout names holder_robot: its
serial line, encoder cards and rates, robot file and base; the twin is the trial's own
(:func:`holder_device`): homing from the zero pose, the arm's dynamics, the world stepped at
:data:`WORLD_HZ`.
"""
from __future__ import annotations

import numpy as np

from droid.cli import RuntimeFailure
from droid.kinematics.transforms import record_pose
from droid.sim.gmf1.lockstep import Gmf1Lockstep
from droid.sim.lockstep import Scheduler

#: The Fanuc twin's world rate in a trial [Hz]: the serial bytes carry their own times (9600
#: baud), the arm integrates at its servo rate inside each step; 240 Hz keeps a trial cheap.
WORLD_HZ = 240.0
HOME_TIMEOUT_S = 30.0
MOVE_TIMEOUT_S = 60.0
SETTLE_S = 0.5
#: A joint move's requested duration [s]; KAREL makes it longer when its speed limits ask.
MOVE_S = 1.0


def holder_device(subunit: str) -> dict:
    """The trial's ``karel_s400`` world-device table of the holder ``subunit`` (the GMF1 builder
    reads it, droid.sim.lockstep_build.BuildContext.world): power-up at the zero pose (homing
    zeroes the counters there, as droid-home does) and the KAREL twin with the robot file's arm
    dynamics.  Its world rate is :data:`WORLD_HZ` (the table's ``rate_hz``)."""
    return {"type": "karel_s400", "subunit": subunit, "start_deg": [0.0] * 6, "dynamics": True}


class Gmf1Holder:
    """The GMF1 in a trial (see the module docstring): the GMF1 package's ``holder`` lockstep model
    (droid.subunits.gmf1.device, ``lockstep_models``), made as ``Gmf1Holder(sched, built,
    q_hold_deg)`` over the subunit its builder built, with its trial world
    (:meth:`trial_world`)."""

    @staticmethod
    def trial_world(subunit: str) -> dict:
        """The ``[world]`` table a trial builds its cell in when this model holds (the builders read
        it, droid.sim.lockstep_build.BuildContext.world): the holder's twin (:func:`holder_device`)
        stepped at :data:`WORLD_HZ`, and no other world device."""
        return {"rate_hz": WORLD_HZ, "devices": {"trial_holder": holder_device(subunit)}}

    def __init__(self, sched: Scheduler, built, q_hold_deg) -> None:
        """``built``: the GMF1 subunit its builder put on ``sched`` (a LockstepSubunit: its
        ``parts``, the :class:`Gmf1Lockstep`; the module docstring); ``q_hold_deg``: the holding
        pose [deg]."""
        self.sched = sched
        self.q_hold = np.asarray(q_hold_deg, float)
        self.g: Gmf1Lockstep = built.parts
        self.model = self.g.model
        self._q_seen = None
        self._T_true = None

    def prepare(self) -> None:
        """Home, then move to the holding pose and settle; RuntimeFailure if either does not finish."""
        self.g.run_ticks(2)  # the serial program opens its port, the encoder reads the cards
        if not self.g.home(HOME_TIMEOUT_S):
            raise RuntimeFailure("the GMF1 did not home")
        counts = np.rint(self.model.gearing.joints_to_counts(self.q_hold)).astype(np.int32)
        cmd = self.g.command_joint(counts, self.g.ticks_for(MOVE_S))
        if not self.g.run_until(lambda: self.g.done(cmd), MOVE_TIMEOUT_S):
            raise RuntimeFailure("the GMF1 did not reach the holding pose")
        self.sched.run_for(SETTLE_S)

    def drift(self, v_mm_s, seconds: float) -> int:
        """Command one cartesian move of the wrist centre by ``v_mm_s * seconds`` [mm] (global
        frame, orientation kept) lasting ``seconds``; returns the command id."""
        T = self.status_pose()
        T[:3, 3] += np.asarray(v_mm_s, float) * seconds
        return self.g.command_cart(T, self.g.ticks_for(seconds))

    def hold(self, T_global_wcp, seconds: float) -> int:
        """The tracker's hold command (gen_hold_robot_wcp, sent once as droid-seamtrack does): a
        cartesian MOVE to ``T_global_wcp`` (4x4, mm) -- the pose it has -- in ``seconds``."""
        return self.g.command_cart(np.asarray(T_global_wcp, float), self.g.ticks_for(seconds))

    def status_pose(self) -> np.ndarray:
        """The GMF1 Status's wrist-centre pose (4x4, mm, global): what the tracker reads."""
        return record_pose(self.g.ctrl_status.read())

    @property
    def name(self) -> str:
        """The holder's subunit name (gmf1; the layout's holder_robot on a cell)."""
        return self.g.sub.name

    def status_fault(self) -> int:
        """The GMF1 Status ``fault`` bits (FAULT_*: FAULT_DEVICE from the serial or encoder program)."""
        return int(self.g.ctrl_status.read()["fault"])

    def true_wcp(self) -> np.ndarray:
        """The true wrist-centre pose (4x4, mm, global) -- the world's, never the tracker's."""
        q = self.g.controller.q_deg
        if q is not self._q_seen:
            self._q_seen, self._T_true = q, self.g.true_pose_global()
        return self._T_true
