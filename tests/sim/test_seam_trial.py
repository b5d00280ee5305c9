"""Seam tracking in lockstep (issue 7, work in progress): the thesis's tracking core
(droid.tasks.seam) driving the Reis (fast arm model) from the camera-and-feature lead
sensor over the step-input workpiece (thesis §6.1.1)."""
import numpy as np
import pytest

from droid.experiments.trial import TrialConfig, run_trial

THESIS_COLUMNS = ["s_mm", "lead_lateral_mm", "lead_depth_mm", "lead_roll_rad", "tool_lateral_mm",
                  "tool_depth_mm", "tool_roll_rad", "yaw_deg", "pitch_deg"]


def short_trial(seed=1):
    return run_trial(TrialConfig("smoke", "i", 16.0, length_mm=300, seed=seed, arm="fast"))


def test_short_step_input_trial_tracks_to_the_end():
    r = short_trial()
    assert r.stop_reason.startswith("end of seam"), (r.stop_reason, r.stop_detail)
    s = r.column("s_mm")
    assert np.nanmax(s) >= 250  # the tool travelled along the seam
    after = s > 150  # past the initial straight section and the 5 degree step at 100 mm
    lat, dep = r.column("tool_lateral_mm")[after], r.column("tool_depth_mm")[after]
    # stated tolerance of this work-in-progress model: RMS lateral <= 4 mm, depth <= 1 mm
    assert np.sqrt(np.nanmean(lat ** 2)) <= 4.0
    assert np.sqrt(np.nanmean(dep ** 2)) <= 1.0


def test_trial_is_deterministic_for_a_seed_and_logs_the_thesis_columns():
    from droid.experiments.trial import COLUMNS

    assert list(COLUMNS[:len(THESIS_COLUMNS)]) == THESIS_COLUMNS
    a, b = short_trial(3), short_trial(3)
    assert len(a.rows) > 100
    assert repr(a.rows) == repr(b.rows)  # identical, NaN (no reading) included


# Summary numbers of short trials as the harness gave them before the speed work (commit
# 05e3b11, the straightforward numpy forms of the camera, feature extraction, arm model and
# tracking core).  The optimised code gives the same rows bit for bit on the machine they were
# computed on; the tolerances leave room for another BLAS's rounding (4x4 products), which a
# closed loop can carry into the last digits.  Re-pinned for issue 12 (mode "listing": the
# literal port; the lead reading now placed with the Reis pose of its capture instant by the
# shared tracking cycle, droid.tasks.seam.cycle, instead of the pose half a tick later): lateral
# RMS moved by < 0.3 %, the micrometre depth RMS by 0.2-0.4 um.
REFERENCE = [
    (dict(position="i", speed_mm_s=16.0, length_mm=300),
     dict(stop="end of seam", rows=396, frames=1200, valid=1200, rms_lat=2.084183245181736,
          rms_dep=0.002142135998653251, stop_s=300.48256846791554)),
    (dict(position="vii", speed_mm_s=64.0, length_mm=500, workpiece="ramp_r500"),
     dict(stop="end of seam", rows=165, frames=510, valid=510, rms_lat=2.9624781216029588,
          rms_dep=0.00183878256469123, stop_s=502.24445838924134)),
    (dict(position="iii", speed_mm_s=16.0, length_mm=300, sensor="ideal"),
     dict(stop="end of seam", rows=396, frames=1200, valid=1200, rms_lat=2.0945811807426793,
          rms_dep=0.0023725948100257015, stop_s=300.48425904996674)),
]


@pytest.mark.parametrize("kw,ref", REFERENCE, ids=["i-16-camera", "vii-64-camera", "iii-16-ideal"])
def test_tracking_result_is_the_reference(kw, ref):
    # the literal port the numbers pin, on the arm, holder and tool-tip sensor they were pinned
    # with (issue 13 makes the full arm, the GMF1's controller and the sensor noise the defaults)
    r = run_trial(TrialConfig("ref", seed=2, mode="listing", arm="fast", holder="fixed", tool_noise=False, **kw))
    s = r.column("s_mm")
    after = s > 150
    lat, dep = r.column("tool_lateral_mm")[after], r.column("tool_depth_mm")[after]
    assert r.stop_reason == ref["stop"]
    assert abs(len(r.rows) - ref["rows"]) <= 1
    assert r.frames == pytest.approx(ref["frames"], abs=3) and r.valid_frames >= ref["valid"] - 3
    assert np.sqrt(np.nanmean(lat ** 2)) == pytest.approx(ref["rms_lat"], rel=0.01)
    assert np.sqrt(np.nanmean(dep ** 2)) == pytest.approx(ref["rms_dep"], rel=0.01)
    assert r.stop_s_mm == pytest.approx(ref["stop_s"], abs=0.5)


def test_dropped_lead_frames_follow_droid_mvs_timeout_rule():
    """A dropped frame brings no line (droid-mvs's station, issue 25): the cycle keeps the reading
    the Status holds, so a 30 % drop rate leaves the lead valid in nearly every log row (it was
    'invalid' in ~30 % before the rule was shared); with every frame dropped, 'invalid' comes by
    the retrace timeout and the seam is lost."""
    from droid.sim.mvs.camera import CameraNoise

    def trial(drop):
        return run_trial(TrialConfig("drop", "i", 16.0, length_mm=100, arm="fast", holder="fixed", seed=2,
                                     noise=CameraNoise(0.5, 0.02, drop)))

    some = trial(0.3)
    assert some.stop_reason == "end of seam" and some.valid_frames < 0.8 * some.frames
    assert np.mean(some.column("lead_valid") == 0) < 0.1
    none = trial(1.0)
    assert none.stop_reason == "seam lost" and none.valid_frames == 0
