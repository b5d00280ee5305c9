"""The neutral 6R arm: what every arm family shares (docs/design.md §12 "One arm, many families").

A family's packages (droid/subunits/<family>/, droid/sim/<family>/) import this one and never
each other (tests/test_device_imports.py):

* :mod:`droid.arm.planner` -- droid-planner: commands -> per-tick joint way-points (``PlannerCore``,
  ``PlannerStation``; thesis §4.1.7), run by every arm whose controller takes way-points (the Reis,
  the ABB on EGM);
* :mod:`droid.arm.pacer` -- ``TickPacer``: when a program that feeds a controller cycles (on the
  relayed tick once the planner wrote, on its own clock when the ticks stop);
* :mod:`droid.arm.rigid_body` -- ``RigidBody``: an arm's M(q), its bias torques and forward dynamics
  from its robot file (Pinocchio or the compiled kernel), for the twins;
* :mod:`droid.arm.arm_dynamics` -- ``ArmDynamics``: an arm behind an industrial controller's joint
  loops (the GMF1's KAREL twin, the ABB's EGM twin);
* :mod:`droid.arm.protocol` -- ``Arm``: what a task drives of one arm, in real time (``BrainArm``)
  and in lockstep (every lockstep builder's ``LockstepSubunit.arm``).

This ``__init__`` imports nothing, so a task can import :mod:`droid.arm.protocol` alone.
"""
