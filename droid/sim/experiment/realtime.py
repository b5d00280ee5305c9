"""``droid-experiment run --realtime``: one trial on the real-time process cell (issue 7).

Not implemented yet: the lead engineer fills in :func:`run_trial_realtime`
(start the seam-tracking cell, place the workpiece, run droid-seamtrack, log
the 10 Hz rows).  Keep the signature: droid.sim.experiment.cli calls it with
the trial's :class:`~droid.sim.experiment.trial.TrialConfig` and the
directory the trial's files go to, and writes the CSV, figure and summary
from the returned :class:`~droid.sim.experiment.trial.TrialResult`.
"""
from __future__ import annotations

import os

from droid.cli import RuntimeFailure
from droid.sim.experiment.trial import TrialConfig, TrialResult


def run_trial_realtime(cfg: TrialConfig, out_dir: str | os.PathLike) -> TrialResult:
    """Run ``cfg`` on the real-time cell and return its log (same columns as the lockstep trial)."""
    raise RuntimeFailure("--realtime: not implemented yet")
