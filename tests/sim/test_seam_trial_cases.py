"""Lockstep seam-tracking trials that must behave as specified (issue 7; thesis §6.2.5):
a transport-delay run, a seam-loss run."""
import numpy as np

from droid.experiments.trial import TrialConfig, run_trial


def test_transport_delay_run_zeroes_then_delays_and_keeps_tracking():
    """§6.2.5: at 150 mm the sensor data are zero for N cycles, then N cycles late; a short
    delay (2 cycles at 8 mm/s, experiment 3.22) has almost no effect (Figure 6.23)."""
    r = run_trial(TrialConfig("3.22", "iii", 8.0, delay_cycles=2, delay_at_mm=150.0, length_mm=260.0, seed=2, arm="fast"))
    assert r.stop_reason == "end of seam", r.stop_detail
    state = [row[15] for row in r.rows]
    travel = r.column("travel_mm")
    first = state.index("delayed") if "zeroed" not in state else state.index("zeroed")
    assert set(state[:first]) == {"off"} and travel[first] >= 150.0 - 8.0 / 10  # one 10 Hz row of travel
    assert state[-1] == "delayed"
    after = travel > 170.0
    lat = r.column("tool_lateral_mm")[after]
    assert np.sqrt(np.nanmean(lat ** 2)) <= 4.0  # still tracking after the delay


def test_seam_loss_run_stops_where_the_lead_sensor_runs_off_the_seam():
    """The run length is longer than the seam: the lead sensor, 100 mm ahead of the tool,
    runs off the workpiece's end and the run stops as 'seam lost' -- not later."""
    r = run_trial(TrialConfig("loss", "i", 32.0, length_mm=2000.0, seed=1, arm="fast"))
    assert r.stop_reason == "seam lost", (r.stop_reason, r.stop_detail)
    # s_mm is the tool's travel, 0 where the sensor starts on the seam start: the sensor runs
    # off 700 mm of seam + 10 mm of lead-out, then LOST_CYCLES + 1 cycles of 32/30 mm pass
    lost_at = 700.0 + 10.0
    assert lost_at - 10.0 <= r.stop_s_mm <= lost_at + 16 * 32.0 / 30.0 + 10.0, r.stop_s_mm
    assert r.column("travel_mm")[-1] < 2000.0


def test_the_ideal_sensor_model_gives_the_camera_chains_numbers():
    """droid-experiment's default sensor model ("ideal": the seam in the field of view plus the
    camera chain's noise) must track like the camera twin + the MVS feature code it stands in
    for: RMS tool error after settling within 0.2 mm, the same stop."""
    from droid.tasks.seam.report import summarize

    out = {}
    for sensor in ("camera", "ideal"):
        r = run_trial(TrialConfig("agree", "iii", 16.0, length_mm=260.0, seed=5, sensor=sensor, arm="fast"))
        out[sensor] = summarize(r.rows, stop_reason=r.stop_reason, camera_to_tcp_mm=r.camera_to_tcp_mm)
    cam, ideal = out["camera"], out["ideal"]
    assert cam.stop_reason == ideal.stop_reason == "end of seam"
    assert cam.settled_rows > 50
    assert abs(cam.rms_lateral_mm - ideal.rms_lateral_mm) <= 0.2
    assert abs(cam.rms_depth_mm - ideal.rms_depth_mm) <= 0.2
