"""The force task's core (issue 27 item 5): gains and their stability limit, the phases of the
admittance controller on a spring contact, and every stop with its reason."""
from __future__ import annotations

import numpy as np
import pytest

from droid.cli import BadInput
from droid.brain.db.layouts import FAULT_BRAKING, FAULT_COLLISION, FAULT_LIMIT, FAULT_LINK, FAULT_SERVO, fault_names
from droid.kinematics.transforms import trans
from droid.tasks.contact.core import (STOP_ARM_FAULT, STOP_ARM_STALE, STOP_END, STOP_FT_STALE, STOP_LOST,
                                      STOP_NO_CONTACT, STOP_OVERFORCE, ArmStatus, ContactStation, FtStatus,
                                      Gains, load_gains)
from tests.refusals import refused

HZ = 60.0
TOOL = trans(0.0, 0.0, 250.0)  # the tool point 250 mm along the WCP's z; its x the tool axis


def test_the_bundled_gains_load_and_keep_a_margin_to_the_limit():
    g = load_gains(heartbeat_hz=HZ)
    assert g == Gains()
    assert g.loop_gain(HZ) == pytest.approx(0.5 * 20.0 * 2 / 60.0)  # K k T = 0.33 < 2


@pytest.mark.parametrize("text, message", [
    ("admittance_mm_per_n_s = 3.0\n", "= 2: the loop is unstable at K k T >= 2"),  # 3 x 20 x 2/60 = 2
    ("admittance_mm_per_n_s = 0.5\ncontact_stiffness_n_per_mm = 200\n", "= 3.33: the loop is unstable"),
    ("admittance_mm_per_n_s = -1\n", "admittance_mm_per_n_s = -1: is outside"),
    ("force_max_n = inf\n", "force_max_n = inf: must be a finite number"),
    ("gain = 1\n", "unknown key 'gain'"),
])
def test_bad_or_unstable_gains_are_refused_in_one_line(tmp_path, text, message):
    msg = refused(tmp_path / "g.toml", text, lambda path: load_gains(path, HZ))
    assert message in msg, msg


class Spring:
    """A surface ``gap_mm`` ahead of the tool along its axis, stiffness k [N/mm]; the arm follows
    its command one cycle late (the command's interpolation)."""

    def __init__(self, k=20.0, gap_mm=3.0):
        self.k, self.gap = k, gap_mm
        self.pose = np.eye(4) @ np.linalg.inv(TOOL)  # WCP such that the tool frame is the identity
        self.pending = None
        self.start = None

    def force(self):
        tool = self.pose @ TOOL
        if self.start is None:
            self.start = tool[:3, 3].copy()
        depth = float(tool[0, 3] - self.start[0]) - self.gap
        return max(0.0, self.k * depth)

    def ft(self, valid=True, stale=False):
        return FtStatus(np.array([-self.force(), 0.0, 0.0]), valid, stale)

    def apply(self, cmd):
        if self.pending is not None:
            self.pose = self.pending
        self.pending = cmd


def run(station, spring, ticks, arm_fault=0, arm_stale=False, ft_kw=None, log=None):
    out = None
    for tick in range(ticks):
        out = station.on_tick(tick, ArmStatus(tick, spring.pose, arm_fault, arm_stale), spring.ft(**(ft_kw or {})))
        if out.cmd is not None:
            spring.apply(out.cmd)
        if log is not None and out.cycle:
            log.append((station.phase, spring.force(), (spring.pose @ TOOL)[2, 3]))
        if out.stop:
            return out
    return out


def test_approach_touch_settle_and_slide_holding_the_force():
    spring, log = Spring(), []
    st = ContactStation(Gains(), HZ, TOOL, force_n=20.0, speed_mm_s=10.0, length_mm=50.0)
    out = run(st, spring, 60 * 20, log=log)
    assert out.stop == STOP_END
    phases = [p for p, _, _ in log]
    assert phases.index("settle") < phases.index("path")
    path = [(f, z) for p, f, z in log if p == "path"]
    assert max(abs(f - 20.0) for f, _ in path[10:]) < 0.5  # the loop holds 20 N
    assert max(f for _, f, _ in log) < 23.0  # no large overshoot at the touch
    assert path[-1][1] == pytest.approx(50.0, abs=0.5)  # 50 mm along the tool's z


@pytest.mark.parametrize("case, want", [
    ("overforce", STOP_OVERFORCE), ("lost", STOP_LOST), ("no contact", STOP_NO_CONTACT),
    ("ft stale", STOP_FT_STALE), ("ft invalid", STOP_FT_STALE), ("arm fault", STOP_ARM_FAULT),
    ("arm stale", STOP_ARM_STALE),
])
def test_every_stop_has_its_reason(case, want):
    spring = Spring(gap_mm=1e6 if case == "no contact" else 3.0)
    st = ContactStation(Gains(), HZ, TOOL, force_n=20.0, speed_mm_s=10.0, length_mm=500.0)
    kw = {}
    if case == "ft stale":
        kw = dict(ft_kw=dict(stale=True))
    elif case == "ft invalid":
        kw = dict(ft_kw=dict(valid=False))
    elif case == "arm fault":
        kw = dict(arm_fault=0x4)
    elif case == "arm stale":
        kw = dict(arm_stale=True)
    if case in ("overforce", "lost"):
        run(st, spring, 60 * 3)  # in contact, on the path
        assert st.phase == "path"
        spring.gap += 10.0 if case == "lost" else -10.0  # the surface drops away / jumps at the tool
    out = run(st, spring, 60 * 20, **kw)
    assert out.stop == want and out.detail, (out.stop, out.detail)
    again = st.on_tick(10 ** 6, ArmStatus(0, spring.pose), spring.ft())
    assert again.stop == want and again.cmd is None  # a stopped station commands nothing more


def test_a_force_outside_the_limit_is_refused():
    with pytest.raises(BadInput, match="force_max_n"):
        ContactStation(Gains(), HZ, TOOL, force_n=80.0, speed_mm_s=10.0, length_mm=50.0)


def test_over_force_between_cycles_stops_at_that_tick():
    """A force past force_max_n read on a tick between two cycles stops the station at once."""
    spring = Spring()
    st = ContactStation(Gains(), HZ, TOOL, force_n=20.0, speed_mm_s=10.0, length_mm=500.0)
    run(st, spring, 60 * 3)  # on the path, holding
    assert st.phase == "path" and st.next_tick is not None
    between = st.next_tick - 1  # cycle_ticks = 2: the tick before the next cycle
    quiet = st.on_tick(between, ArmStatus(between, spring.pose), FtStatus(np.array([-30.0, 0.0, 0.0])))
    assert quiet.stop is None and quiet.cmd is None  # within the limit: nothing until the cycle
    out = st.on_tick(between, ArmStatus(between, spring.pose), FtStatus(np.array([-61.0, 0.0, 0.0])))
    assert out.stop == STOP_OVERFORCE and "61.0 N > 60 N" in out.detail and out.cmd is None
    # a stale or invalid reading between cycles is the cycle's to judge, not an over-force
    st2 = ContactStation(Gains(), HZ, TOOL, force_n=20.0, speed_mm_s=10.0, length_mm=500.0)
    run(st2, Spring(), 60 * 3)
    t = st2.next_tick - 1
    assert st2.on_tick(t, ArmStatus(t, spring.pose), FtStatus(np.array([-99.0, 0, 0]), valid=False)).stop is None


@pytest.mark.parametrize("bits, stops", [(FAULT_BRAKING, True), (FAULT_COLLISION, True), (FAULT_SERVO, True),
                                         (FAULT_LIMIT, False), (FAULT_LINK, False)])
def test_droid_contact_ends_a_press_on_a_protective_stop(bits, stops):
    """Issue 40 item 4: a press that a protective stop (braking, collision) interrupted ends as
    ``arm fault`` naming it, as one on a fault the arm cannot move with; a clamped target or a
    link bit does not (droid-contact's mask, FAULTS_STOP_RUN, on its arm's Status)."""
    from droid.brain.cell.cellfile import builtin_cell_path, load_cell
    from droid.brain.db.layouts import ARM_STATUS, FT6_STATUS
    from droid.tasks.contact import prog

    run = prog.ContactRun(prog.build_parser().parse_args(["arm1"]), load_cell(builtin_cell_path()))
    rec = np.zeros((), ARM_STATUS)
    rec["R"], rec["homed"], rec["tick"], rec["fault"] = np.eye(3), 1, 5, bits
    ft = np.zeros((), FT6_STATUS)
    ft["valid"] = 1
    sent = []
    run.arm.read = lambda: rec
    run.arm.command_cart = lambda T, ticks: sent.append(ticks)
    run.ft_db = type("Ft", (), {"read": staticmethod(lambda: ft)})()
    run.station.T0 = None
    stop = run.on_tick(5)
    if stops:
        assert stop == "arm fault" and run.station.detail.endswith(", ".join(fault_names(bits))), run.station.detail
        assert sent == []
    else:
        assert stop is None


@pytest.mark.parametrize("bits, kept", [(FAULT_BRAKING, FAULT_BRAKING), (FAULT_COLLISION | FAULT_LINK, FAULT_COLLISION),
                                        (FAULT_LIMIT, 0), (FAULT_LINK, 0)])
def test_both_runners_judge_the_arm_status_by_the_same_mask(bits, kept):
    """droid-contact and the lockstep contact trial read the arm's Status through one
    constructor, ``ArmStatus.of_record``: its pose and stale flag as recorded, and only the fault
    bits that end a press (FAULTS_STOP_RUN) -- the lockstep trial stopped on any bit before."""
    from droid.brain.db.layouts import ARM_STATUS

    rec = np.zeros((), ARM_STATUS)
    rec["R"], rec["x"], rec["y"], rec["z"], rec["tick"], rec["fault"], rec["stale"] = np.eye(3), 1.0, 2.0, 3.0, 7, bits, 1
    a = ArmStatus.of_record(rec)
    assert a.fault == kept and a.tick == 7 and a.stale is True
    assert np.array_equal(a.pose[:3, 3], [1.0, 2.0, 3.0]) and np.array_equal(a.pose[:3, :3], np.eye(3))
