"""The experiment matrix of thesis chapter 6 (Tables 6.1-6.3, experiments 4 and 5) as data."""
import pytest

from droid.cli import BadInput
from droid.experiments import matrix

E = matrix.experiments()


def ids(prefix, n):
    return [f"{prefix}.{i}" for i in range(1, n + 1)]


def test_every_id_of_the_tables_exists_once_and_nothing_else():
    expected = ids(1, 41) + ids(2, 5) + ids(3, 28) + ids(4, 4) + ["5.1"]
    assert list(E) == expected
    for name, n in [("table6.1", 41), ("table6.2", 5), ("table6.3", 28), ("exp4", 4), ("exp5", 1)]:
        assert [e.id for e in matrix.resolve([name])] == [e for e in expected if E[e].table == name]
        assert len(matrix.resolve([name])) == n
    assert [e.id for e in matrix.resolve(["all"])] == expected


# Spot checks against the printed tables (thesis Table 6.1, 6.2, 6.3; §6.2.6-6.2.7):
# id: (position, speed mm/s, workpiece, yaw gain, pitch gain, delay cycles, wrist)
SPOT = {
    "1.1": ("i", 4, "step_input", 0.15, 0.25, 0, "standard"),
    "1.7": ("ii", 8, "step_input", 0.15, 0.25, 0, "standard"),
    "1.12": ("iii", 8, "step_input", 0.15, 0.25, 0, "standard"),  # Fig 6.5: 30 deg roll at 8 mm/s
    "1.15": ("iii", 64, "step_input", 0.15, 0.25, 0, "standard"),
    "1.17": ("iv", 8, "step_input", 0.15, 0.25, 0, "standard"),
    "1.22": ("v", 8, "step_input", 0.15, 0.25, 0, "standard"),
    "1.25": ("v", 64, "step_input", 0.15, 0.25, 0, "standard"),
    "1.26": ("vii", 4, "ramp_r500", 0.15, 0.25, 0, "standard"),
    "1.33": ("vii", 32, "ramp_r400", 0.15, 0.25, 0, "standard"),
    "1.36": ("vii", 16, "ramp_r300", 0.15, 0.25, 0, "standard"),
    "1.41": ("vii", 32, "ramp_r200", 0.15, 0.25, 0, "standard"),
    "2.1": ("vi", 4, "step_input", 0.15, 0.25, 0, "standard"),
    "2.5": ("vi", 64, "step_input", 0.15, 0.25, 0, "standard"),
    "3.1": ("iii", 16, "step_input", 0.15, 0.05, 0, "standard"),
    "3.5": ("iii", 16, "step_input", 0.15, 0.45, 0, "standard"),
    "3.6": ("iii", 16, "step_input", 0.05, 0.15, 0, "standard"),
    "3.9": ("iii", 16, "step_input", 0.55, 0.15, 0, "standard"),  # printed "Kp (pitch) = 0.55": a yaw gain
    "3.10": ("iii", 16, "step_input", 0.75, 0.15, 0, "standard"),
    "3.13": ("iii", 32, "step_input", 0.15, 0.25, 0, "standard"),
    "3.18": ("iii", 32, "step_input", 0.35, 0.15, 0, "standard"),
    "3.21": ("iii", 8, "step_input", 0.15, 0.25, 1, "standard"),
    "3.23": ("iii", 8, "step_input", 0.15, 0.25, 4, "standard"),
    "3.27": ("iii", 8, "step_input", 0.15, 0.25, 8, "standard"),
    "3.28": ("iii", 8, "step_input", 0.15, 0.25, 16, "standard"),
    "4.3": ("iii", 16, "step_input", 0.15, 0.25, 0, "standard"),
    "5.1": ("i", 16, "step_input", 0.1, 0.05, 0, "extension30"),
}


@pytest.mark.parametrize("eid", sorted(SPOT))
def test_spot_check_against_the_thesis_tables(eid):
    c = E[eid].config
    pos, speed, wp, yaw, pitch, delay, wrist = SPOT[eid]
    assert (c.position, c.speed_mm_s, c.workpiece, c.delay_cycles, c.wrist) == (pos, speed, wp, delay, wrist)
    assert c.yaw_gain == pytest.approx(yaw) and c.pitch_gain == pytest.approx(pitch)
    assert c.trial_id == eid and eid in c.title


def test_sweeps_cover_the_thesis_values():
    speeds = [E[f"1.{i}"].config.speed_mm_s for i in range(1, 26)]
    assert speeds == [4, 8, 16, 32, 64] * 5
    assert [E[f"1.{i}"].config.speed_mm_s for i in range(26, 42)] == [4, 8, 16, 32] * 4
    assert [E[f"1.{i}"].config.position for i in range(1, 26, 5)] == ["i", "ii", "iii", "iv", "v"]
    assert [E[f"3.{i}"].config.pitch_gain for i in range(1, 6)] == [0.05, 0.15, 0.25, 0.35, 0.45]
    assert [E[f"3.{i}"].config.yaw_gain for i in range(16, 21)] == [0.05, 0.25, 0.35, 0.55, 0.75]
    assert {E[f"3.{i}"].config.speed_mm_s for i in range(11, 21)} == {32.0}
    assert [E[f"3.{i}"].config.delay_cycles for i in range(21, 29)] == [1, 2, 4, 5, 6, 7, 8, 16]
    assert {E[f"3.{i}"].config.delay_at_mm for i in range(21, 29)} == {150.0}
    assert all(E[i].config.position == "iii" for i in ids(3, 28) + ids(4, 4))
    # the figures with the yaw/pitch panels: Table 6.2, experiments 4 and 5
    assert {eid for eid, e in E.items() if e.config.panels == "angles"} == set(ids(2, 5) + ids(4, 4) + ["5.1"])


def test_unknown_names_are_bad_input_listing_the_valid_forms():
    for bad in ["1.42", "3.29", "6.1", "table6.4", "", "exp"]:
        with pytest.raises(BadInput, match="table6.1, table6.2, table6.3, exp4, exp5, all"):
            matrix.resolve([bad])


def test_resolve_drops_duplicates_and_accepts_a_trailing_dot():
    assert [e.id for e in matrix.resolve(["3.1.", "3.1", "TABLE6.2", "2.3"])] == ["3.1"] + ids(2, 5)


def test_seeds_are_derived_deterministically_and_differ_per_id():
    a = [matrix.with_seed(E[i], 1).config.seed for i in ids(4, 4)]
    assert a == [matrix.with_seed(E[i], 1).config.seed for i in ids(4, 4)]
    assert len(set(a)) == 4
    assert a != [matrix.with_seed(E[i], 2).config.seed for i in ids(4, 4)]
    assert all(0 <= s < 2 ** 31 for s in a)
