"""The experiment matrix of thesis chapter 6 as data: every trial ID -> a TrialConfig.

===========  ==========  ===================================================================
name         IDs         what (thesis)
===========  ==========  ===================================================================
table6.1     1.1-1.41    Table 6.1 (§6.2.1): step input at positions i, ii, iii (30° roll),
                         iv (45° roll), v (30° pitch) at 4/8/16/32/64 mm/s; ramp input,
                         vertical (position vii), radius 500/400/300/200 mm at 4/8/16/32
                         mm/s.  Gains yaw 0.15, pitch 0.25.
table6.2     2.1-2.5     Table 6.2 (§6.2.3): step input along the xy radial (vi), 4..64 mm/s;
                         figures with the yaw and pitch angles (Figures 6.14-6.19).
table6.3     3.1-3.28    Table 6.3 (§6.2.5): 30° roll (iii).  3.1-3.5 pitch gain 0.05..0.45
                         (yaw 0.15), 3.6-3.10 yaw gain 0.05/0.25/0.35/0.55/0.75 (pitch
                         0.15), at 16 mm/s; 3.11-3.20 the same at 32 mm/s; 3.21-3.28
                         transport delays of 1/2/4/5/6/7/8/16 cycles at 8 mm/s inserted
                         at 150 mm, gains 0.15/0.25.
exp4         4.1-4.4     Experiment 4 (§6.2.6): repeatability, iii at 16 mm/s, 4 seeds; the
                         per-s standard deviations across the runs (Figures 6.31-6.32).
exp5         5.1         Experiment 5 (§6.2.7): the 30° extension block, position i at
                         16 mm/s, gains the "optimal" 0.4/0.2 divided by 4: yaw 0.1, pitch 0.05.
===========  ==========  ===================================================================

Reading of Table 6.3 3.6-3.10 / 3.16-3.20: the printed table labels 3.7-3.10
(and 3.17-3.20) "Kp (pitch)", but the text of §6.2.5 says these are the yaw
gain runs ("For the Yaw gain experiments, the Pitch gain is kept constant at
0.15") and §6.1.2 lists the yaw gain values 0.05, 0.15, 0.25, 0.35, 0.55,
0.75 while the pitch gain stops at 0.45 -- 0.55 and 0.75 can only be yaw
gains.  So 3.6-3.10 are yaw 0.05, 0.25, 0.35, 0.55, 0.75 with pitch 0.15
(yaw 0.15 / pitch 0.15 is run 3.2).  The "Yaw gain varied at 0.25, 0.35 and
0.75" of §6.2.5's text is read as a shortened list of the same runs.

Trial seeds: :func:`derive_seed` (base seed, ID) -> a fixed 31-bit seed, so
4.1-4.4 differ from one another and every run of the same command repeats.
"""
from __future__ import annotations

import hashlib
from dataclasses import dataclass, replace

from droid.cli import BadInput
from droid.experiments.trial import TrialConfig

SPEEDS_MM_S = (4.0, 8.0, 16.0, 32.0, 64.0)  # §6.1.2
RAMP_SPEEDS_MM_S = (4.0, 8.0, 16.0, 32.0)  # Table 6.1: 64 mm/s not run on the ramp (workspace interference)
DEFAULT_YAW_GAIN, DEFAULT_PITCH_GAIN = 0.15, 0.25  # §6.2.1
DELAY_AT_MM = 150.0  # §6.1.2: "running the Seam Tracking program for 150mm ... then a single delay"
CYCLE_HZ = 30.0

#: Experiment table names, in order, with their titles.
TABLES = {
    "table6.1": "Table 6.1: travel speed and position/orientation",
    "table6.2": "Table 6.2: stability with respect to radial distance and travel speed",
    "table6.3": "Table 6.3: stability with respect to gains and transport delays",
    "exp4": "Experiment 4: repeatability (4 runs, 30° roll, 16 mm/s)",
    "exp5": "Experiment 5: alternate wrist (30° extension block), gains / 4",
}
ALL = "all"

#: Orientation/position labels of the layout's positions (Figure 6.4, §6.1.2).
POSITION_LABELS = {
    "i": "0° roll, 0° pitch, position (i)",
    "ii": "0° roll, 0° pitch, (i) +300 mm lateral",
    "iii": "30° roll, 0° pitch, position (i)",
    "iv": "45° roll, 0° pitch, position (i)",
    "v": "0° roll, 30° pitch, position (i)",
    "vi": "0° roll, 0° pitch, on xy radial",
    "vii": "0° roll, 90° pitch (vertical)",
}


@dataclass(frozen=True)
class Experiment:
    """One row of an experiment table."""

    id: str
    table: str  # a key of TABLES
    track: str  # "step input", "ramp r500", ...
    setting: str  # the gains / delay column
    config: TrialConfig

    def describe(self) -> str:
        """One line: ID, table, track, speed, position, gains/delay, wrist."""
        c = self.config
        wrist = "" if c.wrist == "standard" else f", wrist {c.wrist}"
        return (f"{self.id:<5} {self.table:<8} {self.track:<11} {c.speed_mm_s:>4g} mm/s  "
                f"{c.position:<3} {POSITION_LABELS[c.position]:<38} {self.setting}{wrist}")


def _gains(yaw: float, pitch: float) -> str:
    return f"Kp yaw {yaw:g}, pitch {pitch:g}"


def _delay(cycles: int) -> str:
    return f"delay {cycles} cycles ({1000.0 * cycles / CYCLE_HZ:.1f} ms) at {DELAY_AT_MM:g} mm; " + \
        _gains(DEFAULT_YAW_GAIN, DEFAULT_PITCH_GAIN)


def _exp(eid: str, table: str, position: str, speed: float, *, workpiece: str = "step_input",
         yaw: float = DEFAULT_YAW_GAIN, pitch: float = DEFAULT_PITCH_GAIN, delay: int = 0,
         wrist: str = "standard", panels: str = "errors") -> Experiment:
    track = "step input" if workpiece == "step_input" else workpiece.replace("_", " ")
    setting = _delay(delay) if delay else _gains(yaw, pitch)
    title = f"{eid}: {track}, {speed:g} mm/s, {POSITION_LABELS[position]}, {setting}"
    if wrist != "standard":
        title += f", wrist {wrist}"
    cfg = TrialConfig(trial_id=eid, position=position, speed_mm_s=speed, workpiece=workpiece, yaw_gain=yaw,
                      pitch_gain=pitch, delay_cycles=delay, delay_at_mm=DELAY_AT_MM, wrist=wrist, title=title,
                      panels=panels)
    return Experiment(eid, table, track, setting, cfg)


def _table_6_1() -> list[Experiment]:
    out = []
    n = 1
    for position in ("i", "ii", "iii", "iv", "v"):  # 1.1-1.25
        for v in SPEEDS_MM_S:
            out.append(_exp(f"1.{n}", "table6.1", position, v))
            n += 1
    for radius in (500, 400, 300, 200):  # 1.26-1.41
        for v in RAMP_SPEEDS_MM_S:
            out.append(_exp(f"1.{n}", "table6.1", "vii", v, workpiece=f"ramp_r{radius}"))
            n += 1
    return out


def _table_6_2() -> list[Experiment]:
    return [_exp(f"2.{n}", "table6.2", "vi", v, panels="angles") for n, v in enumerate(SPEEDS_MM_S, start=1)]


PITCH_GAINS = (0.05, 0.15, 0.25, 0.35, 0.45)  # 3.1-3.5, 3.11-3.15 (yaw 0.15)
YAW_GAINS = (0.05, 0.25, 0.35, 0.55, 0.75)  # 3.6-3.10, 3.16-3.20 (pitch 0.15); see the module docstring
DELAYS_CYCLES = (1, 2, 4, 5, 6, 7, 8, 16)  # 3.21-3.28


def _table_6_3() -> list[Experiment]:
    out = []
    n = 1
    for v in (16.0, 32.0):
        for kp in PITCH_GAINS:
            out.append(_exp(f"3.{n}", "table6.3", "iii", v, yaw=0.15, pitch=kp))
            n += 1
        for ky in YAW_GAINS:
            out.append(_exp(f"3.{n}", "table6.3", "iii", v, yaw=ky, pitch=0.15))
            n += 1
    for d in DELAYS_CYCLES:
        out.append(_exp(f"3.{n}", "table6.3", "iii", 8.0, delay=d))
        n += 1
    return out


EXP4_RUNS = 4


def _exp4() -> list[Experiment]:
    return [_exp(f"4.{n}", "exp4", "iii", 16.0, panels="angles") for n in range(1, EXP4_RUNS + 1)]


def _exp5() -> list[Experiment]:
    # §6.2.7: "the gains were lowered by a factor of 4 to 0.1 kp(yaw) and 0.05 for kp(pitch)"
    return [_exp("5.1", "exp5", "i", 16.0, yaw=0.4 / 4, pitch=0.2 / 4, wrist="extension30", panels="angles")]


def experiments() -> dict[str, Experiment]:
    """Every experiment by ID, in table order."""
    out: dict[str, Experiment] = {}
    for e in _table_6_1() + _table_6_2() + _table_6_3() + _exp4() + _exp5():
        out[e.id] = e
    return out


def valid_forms() -> str:
    return ("IDs 1.1-1.41, 2.1-2.5, 3.1-3.28, 4.1-4.4, 5.1, or a table: "
            + ", ".join(list(TABLES) + [ALL]))


def resolve(names) -> list[Experiment]:
    """IDs and table names -> experiments (table order within a name, duplicates dropped).

    Raises BadInput naming the valid forms for an unknown name.
    """
    table = experiments()
    out: dict[str, Experiment] = {}
    for name in names:
        key = name.strip().lower()
        if key == ALL:
            picked = list(table.values())
        elif key in TABLES:
            picked = [e for e in table.values() if e.table == key]
        elif key.rstrip(".") in table:
            picked = [table[key.rstrip(".")]]
        else:
            raise BadInput(f"unknown experiment {name!r}: {valid_forms()}")
        for e in picked:
            out.setdefault(e.id, e)
    if not out:
        raise BadInput(f"no experiment named: {valid_forms()}")
    return list(out.values())


def derive_seed(base_seed: int, trial_id: str) -> int:
    """A fixed 31-bit seed from the base seed and the trial ID (same inputs -> same seed)."""
    digest = hashlib.sha256(f"{int(base_seed)}:{trial_id}".encode()).digest()
    return int.from_bytes(digest[:4], "little") & 0x7FFFFFFF


def with_seed(e: Experiment, base_seed: int) -> Experiment:
    return replace(e, config=replace(e.config, seed=derive_seed(base_seed, e.id)))
