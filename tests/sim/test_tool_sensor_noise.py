"""The tool-tip sensor sees through the lead sensor's noise model (issue 13 item 5): the ideal
sensor model's scatter scaled by the camera's stripe jitter, seeded and deterministic."""
import numpy as np
import pytest

from droid.sim.mvs.trial_sensors import DEFAULT_NOISE, IDEAL_SIGMA_Y_MM, ToolTipSensor
from droid.sim.mvs.crossing import SeamCrossing
from droid.experiments.trial import TrialConfig, run_trial
from droid.sim.mvs.camera import CameraNoise
from droid.sim.mvs.devices import ToolSensorCore
from droid.sim.mvs.tool_sensor import (SIGMA_HEIGHT_MM, SIGMA_LATERAL_MM, SIGMA_ROLL_RAD, ToolNoise, ToolReading,
                                       noisy, pose_for_reading)
from droid.sim.workpiece import load_workpiece
from droid.brain.plumbing.sensor_line import parse_line


def test_the_noise_model_is_the_lead_sensors():
    n = ToolNoise.like_camera(DEFAULT_NOISE)
    assert (n.sigma_height_mm, n.sigma_lateral_mm, n.sigma_roll_rad) == (SIGMA_HEIGHT_MM, SIGMA_LATERAL_MM,
                                                                          SIGMA_ROLL_RAD)
    assert SIGMA_LATERAL_MM == IDEAL_SIGMA_Y_MM
    assert ToolNoise.like_camera(CameraNoise()).exact
    assert ToolNoise.like_camera(CameraNoise(jitter_px=1.0)).sigma_lateral_mm == pytest.approx(2 * SIGMA_LATERAL_MM)
    with pytest.raises(ValueError):
        ToolNoise(sigma_lateral_mm=-1.0)


def test_noisy_readings_scatter_by_the_sigmas_and_repeat_per_seed():
    truth = ToolReading(lateral_mm=0.3, height_mm=-0.2, roll_rad=0.01, s_mm=42.0)
    n = ToolNoise.like_camera(DEFAULT_NOISE)
    draws = [noisy(truth, n, rng) for rng in [np.random.default_rng(7)] for _ in range(4000)]
    lat = np.array([d.lateral_mm for d in draws])
    hgt = np.array([d.height_mm for d in draws])
    assert np.std(lat) == pytest.approx(SIGMA_LATERAL_MM, rel=0.1)
    assert np.std(hgt) == pytest.approx(SIGMA_HEIGHT_MM, rel=0.1)
    assert abs(np.mean(lat) - 0.3) < 0.005 and all(d.s_mm == 42.0 for d in draws)
    again = [noisy(truth, n, rng) for rng in [np.random.default_rng(7)] for _ in range(10)]
    assert again == draws[:10]
    assert noisy(None, n, np.random.default_rng(1)) is None
    assert noisy(truth, ToolNoise(drop_probability=1.0), np.random.default_rng(1)) is None


def test_the_world_devices_core_writes_noisy_seeded_lines():
    wp = load_workpiece("step_input")
    T = pose_for_reading(wp, 50.0, 0.0, 0.5, 0.0)
    lines = lambda seed: [ToolSensorCore(wp, ToolNoise.like_camera(DEFAULT_NOISE), seed).step(T) for _ in range(1)]
    core = ToolSensorCore(wp, ToolNoise.like_camera(DEFAULT_NOISE), 3)
    ys = [parse_line(core.step(T).rstrip(b"\n")).y_mm for _ in range(200)]
    assert 0.03 < np.std(ys) < 0.09 and abs(np.mean(ys) - 0.5) < 0.02
    again = ToolSensorCore(wp, ToolNoise.like_camera(DEFAULT_NOISE), 3)
    assert [parse_line(again.step(T).rstrip(b"\n")).y_mm for _ in range(200)] == ys
    exact = ToolSensorCore(wp)
    assert parse_line(exact.step(T).rstrip(b"\n")).y_mm == pytest.approx(0.5, abs=1e-3)
    assert lines(1) != lines(2)


def test_a_trials_tool_columns_carry_the_noise_and_nothing_else_changes():
    """With the ``ideal`` lead sensor (its scatter does not depend on the camera noise) the same
    trial with and without stripe jitter moves the arm identically: the tool columns differ by
    the tool-tip sensor's scatter only."""
    kw = dict(trial_id="t", position="i", speed_mm_s=16.0, length_mm=200.0, sensor="ideal", holder="fixed")
    noisy_run = run_trial(TrialConfig(noise=DEFAULT_NOISE, **kw))
    exact_run = run_trial(TrialConfig(noise=CameraNoise(), **kw))
    np.testing.assert_array_equal(noisy_run.column("s_mm"), exact_run.column("s_mm"))
    d = noisy_run.column("tool_lateral_mm") - exact_run.column("tool_lateral_mm")
    d = d[np.isfinite(d)]
    assert d.size > 50
    assert np.std(d) == pytest.approx(SIGMA_LATERAL_MM, rel=0.3)
    again = run_trial(TrialConfig(noise=DEFAULT_NOISE, **kw))
    assert again.rows == noisy_run.rows  # seeded: the same trial twice is the same log
