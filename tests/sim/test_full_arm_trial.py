"""The experiments' default arm model is the full Reis (issue 13 item 5): every core and the plant
twin, homed from its own power-up pose before each repetition."""
import numpy as np

from droid.experiments.trial import TrialConfig, run_trial


def test_the_default_arm_is_full_and_each_repetition_homes_from_its_own_power_up_pose(monkeypatch):
    from droid.sim import trial_cell

    homed = []
    original = trial_cell.FullArm.prepare

    def prepare(self):
        homed.append(self.arm.plant.joint_deg.copy())  # the power-up pose before the homing
        original(self)
        assert int(self.arm.status["homed"]) == 1

    monkeypatch.setattr(trial_cell.FullArm, "prepare", prepare)
    assert TrialConfig("d", "i", 16.0).arm == "full"
    results = [run_trial(TrialConfig("rep", "iii", 16.0, length_mm=200.0, seed=s, sensor="ideal")) for s in (1, 2)]
    assert len(homed) == 2 and np.abs(homed[0] - homed[1]).max() > 1.0  # two homings, two power-up poses
    for r in results:
        assert r.prep_s > 5.0  # homing + the move to the start pose, simulated
        assert r.stop_reason == "end of seam", (r.stop_reason, r.stop_detail)
        s = r.column("s_mm")
        lat = r.column("tool_lateral_mm")[s > 150]
        assert np.sqrt(np.nanmean(lat ** 2)) < 1.0  # generous: ~0.2-0.3 mm measured (docs/experiments.md)
    # the repetitions differ (power-up pose, homing, sensor noise) but not by much
    a, b = (np.sqrt(np.nanmean(r.column("tool_lateral_mm")[r.column("s_mm") > 150] ** 2)) for r in results)
    assert a != b
