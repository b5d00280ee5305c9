"""The program cycles shared by the real-time shells and lockstep (issue 17 item 1): stations.

Each station is driven here with in-memory records, fake drivers and hand-made
messages -- what a shell or LockstepArm hands it -- and checked on what it writes.
"""
import numpy as np

from droid.brain.db import arm_command
from droid.brain.db import layouts as L
from droid.brain.cell.classes import ARM6R
from droid.brain.runtime.remote import RemoteStation, StatusTranslator
from droid.brain.db.shmdb import MemoryDatabase
from droid.subunits.agent import AgentStation
from droid.subunits.reis import servo_wire as sw
from droid.subunits.reis import vme_map as vm
from droid.subunits.reis.servo import ServoCore
from droid.subunits.reis.servo_agent import ServoAgentCore
from droid.subunits.reis.servo_params import Mode, ServoParams
from droid.subunits.reis.station import ServoAgentStation, ServoStation, WatchdogStation
from droid.subunits.reis.watchdog import WatchdogCore

P = 16_666_667  # heartbeat period [ns]


def report(tick=4, fault=0, homed=True, pos=(1000,) * 6) -> bytes:
    return sw.pack_status(sw.ServoReport(tick=tick, mode=int(Mode.NORMAL), homed=homed, homing_joint=-1,
                                         starved=False, braking=False, fault=fault, amps_on=True,
                                         encoder_pos=pos, encoder_cmd=pos, following_error=(0,) * 6,
                                         dac=(0,) * 6))


class FakeBus:
    def __init__(self):
        self.kicks, self.dacs, self.amp_status = [], [], 0

    def write_watchdog(self, a, b):
        self.kicks.append((a, b))

    def read_amp_status(self):
        return self.amp_status

    def read_encoders_raw(self):
        return (0,) * 6

    def read_limit_switches(self):
        return (False,) * 6

    def write_dacs(self, dacs):
        self.dacs.append(dacs)

    amps_powered = True


def test_servo_modes_are_the_records_cmd_mode_numbers():
    assert Mode is L.CmdMode
    agent = ServoAgentCore()
    cmd = L.new_record(L.CTRL_COMMAND_LAYOUT)
    cmd["link_alive"], cmd["cmd_mode"], cmd["cmd_id"] = 1, L.HOME_MODE, 7
    d = agent.step(cmd, sw.unpack_status(report(homed=False)), True)
    assert d.message.mode == int(L.HOME_MODE) == 2  # passed through, no mapping table
    old = b"DSC1" + sw.pack_command(d.message)[4:]  # a servo message of the old numbering
    st = ServoStation(ServoCore(ServoParams()), FakeBus())
    assert not st.take(old) and st.bad_frames == 1


def test_servo_station_reads_steps_writes_and_reports_every_few_ticks():
    bus = FakeBus()
    st = ServoStation(ServoCore(ServoParams()), bus)
    reports = [st.cycle() for _ in range(2 * sw.STATUS_EVERY_TICKS)]
    assert len(bus.dacs) == 2 * sw.STATUS_EVERY_TICKS
    sent = [r for r in reports if r is not None]
    assert len(sent) == 2 and sw.unpack_status(sent[-1]).tick == st.core.tick
    assert st.take(sw.pack_command(sw.ServoCommand(1, int(Mode.JOG), (5,) * 6)))


def test_watchdog_station_kicks_only_after_the_servo_spoke_and_reports_the_latch():
    status = MemoryDatabase("ctrl_status", L.CTRL_STATUS_LAYOUT)
    bus = FakeBus()
    wd = WatchdogStation(WatchdogCore(), bus, status)
    assert not wd.cycle() and bus.kicks == []  # no kick before the servo's first status
    wd.take(b"garbage")
    assert wd.bad_frames == 1
    for tick in (4, 8, 12):
        wd.take(report(tick=tick))
        assert wd.cycle()
    assert len(bus.kicks) == 3 and not int(status.read()["fault"]) & L.FAULT_WATCHDOG
    bus.amp_status = vm.AMP_STATUS_WATCHDOG_FAULT
    wd.cycle()
    assert int(status.read()["fault"]) & L.FAULT_WATCHDOG
    bus.amp_status = 0
    wd.cycle()
    assert not int(status.read()["fault"]) & L.FAULT_WATCHDOG


def test_servo_agent_station_needs_a_fresh_status_and_keeps_the_watchdogs_fault_bit():
    cmd = MemoryDatabase("ctrl_command", L.CTRL_COMMAND_LAYOUT)
    status = MemoryDatabase("ctrl_status", L.CTRL_STATUS_LAYOUT)
    cmd.update(link_alive=1, cmd_mode=L.JOG_MODE, cmd_id=0)
    status.update(fault=L.FAULT_WATCHDOG)
    st = ServoAgentStation(ServoAgentCore(), cmd, status, command_hz=60.0)
    st.take(report(), 1_000_000_000)
    msg = st.cycle(1_000_000_000 + 3 * P - 2)  # fresh for three command periods
    assert msg is not None and sw.unpack_command(msg).mode == Mode.JOG
    assert int(status.read()["fault"]) == L.FAULT_WATCHDOG
    assert st.cycle(1_000_000_000 + 3 * P) is None  # silent servo: nothing sent, FAULT_SERVO
    assert int(status.read()["fault"]) == L.FAULT_WATCHDOG | L.FAULT_SERVO
    assert list(status.read()["encoder_pos"]) == [1000] * 6


def test_servo_agent_station_judges_freshness_by_the_cells_stale_ticks():
    """A cell with stale_ticks = 12 (a host with long stalls) keeps a status fresh for 12
    command periods, not 3: one silence rule for every link (issue 16)."""
    cmd = MemoryDatabase("ctrl_command", L.CTRL_COMMAND_LAYOUT)
    status = MemoryDatabase("ctrl_status", L.CTRL_STATUS_LAYOUT)
    cmd.update(link_alive=1, cmd_mode=L.JOG_MODE, cmd_id=0)
    st = ServoAgentStation(ServoAgentCore(stale_ticks=12), cmd, status, command_hz=60.0)
    st.take(report(), 1_000_000_000)
    assert st.cycle(1_000_000_000 + 11 * P) is not None
    assert not int(status.read()["fault"]) & L.FAULT_SERVO
    assert st.cycle(1_000_000_000 + 12 * P) is None
    assert int(status.read()["fault"]) & L.FAULT_SERVO


def test_servo_agent_station_does_not_blame_the_servo_for_its_own_stall():
    """A cycle that itself runs late (the whole host stalled) judges the servo's silence
    only over the time the agent was awake; past that the servo is silent again."""
    cmd = MemoryDatabase("ctrl_command", L.CTRL_COMMAND_LAYOUT)
    status = MemoryDatabase("ctrl_status", L.CTRL_STATUS_LAYOUT)
    cmd.update(link_alive=1, cmd_mode=L.JOG_MODE, cmd_id=0)
    st = ServoAgentStation(ServoAgentCore(), cmd, status, command_hz=60.0)
    st.take(report(), 1_000_000_000)
    stall = 200_000_000  # [ns]
    assert st.cycle(1_000_000_000 + stall, late_ns=stall) is not None
    assert not int(status.read()["fault"]) & L.FAULT_SERVO
    assert st.cycle(1_000_000_000 + stall + 3 * P, late_ns=0) is None
    assert int(status.read()["fault"]) & L.FAULT_SERVO


def test_servo_agent_after_its_own_gap_does_not_send_a_way_point_on_drained_old_reports():
    """The agent stopped (SIGSTOP, starved of CPU) for 1.5 s while the servo ran on and braked.
    The reports it drains on waking are a queue from the start of the gap: not starved, the
    old target.  On them alone, the planner's way-point of now (1.5 s farther along a slow move,
    yet within two periods at full speed) would pass every check and the servo would jump to it.
    So a cycle whose newest report is more servo ticks past the last cycle's than a stale window
    holds commands nothing (FAULT_BRAKING: the planner cancels); the live reports then show the
    servo braked, and the agent waits for the planner to re-anchor where the arm stands."""
    cmd = MemoryDatabase("ctrl_command", L.CTRL_COMMAND_LAYOUT)
    status = MemoryDatabase("ctrl_status", L.CTRL_STATUS_LAYOUT)
    st = ServoAgentStation(ServoAgentCore(), cmd, status, command_hz=60.0)

    def rep(tick, pos, starved=False):
        return sw.pack_status(sw.ServoReport(tick=tick, mode=int(Mode.NORMAL), homed=True, homing_joint=-1,
                                             starved=starved, braking=False, fault=0, amps_on=True,
                                             encoder_pos=(pos,) * 6, encoder_cmd=(pos,) * 6,
                                             following_error=(0,) * 6, dac=(0,) * 6))

    t, tick, wp = 10**9, 1000, 1000
    for k in range(1, 6):  # a slow move: 2 counts per period
        wp += 2
        cmd.update(link_alive=1, cmd_mode=L.NORMAL_MODE, cmd_id=1, brain_tick=k, planner_tick=k,
                   encoder_cmd_int=(wp,) * 6, plan_ext=(5000,) * 6)
        tick += 8
        st.take(rep(tick, wp - 2), t + k * P - 1000)
        assert st.cycle(t + k * P) is not None
    # the gap: 1.5 s (90 periods); the planner moved on 180 counts, the servo braked at ~wp
    k += 90
    cmd.update(brain_tick=k, planner_tick=k, encoder_cmd_int=(wp + 180,) * 6)
    now = t + k * P
    for j in range(1, 31):  # the drained queue: the reports of the gap's first 240 ms
        st.take(rep(tick + 4 * j, wp), now - 1000)
    assert st.cycle(now, late_ns=90 * P) is None
    assert "catching up" in st.last.why
    assert int(status.read()["fault"]) & L.FAULT_BRAKING
    # the next cycle drains the rest: the live reports say the servo braked and holds at wp
    k += 1
    cmd.update(brain_tick=k, planner_tick=k, encoder_cmd_int=(wp + 182,) * 6)
    st.take(rep(tick + 8 * 91, wp, starved=True), t + k * P - 1000)
    assert st.cycle(t + k * P) is None  # still the catching-up period (its span is long too)
    k += 1
    st.take(rep(tick + 8 * 92, wp, starved=True), t + k * P - 1000)
    cmd.update(brain_tick=k, planner_tick=k, encoder_cmd_int=(wp + 184,) * 6)
    assert st.cycle(t + k * P) is None
    assert st.last.why == "waiting for the planner to re-anchor"
    # the planner re-anchors where the arm stands: commanded again, from there
    k += 1
    st.take(rep(tick + 8 * 93, wp, starved=True), t + k * P - 1000)
    cmd.update(brain_tick=k, planner_tick=k, encoder_cmd_int=(wp,) * 6)
    msg = st.cycle(t + k * P)
    assert msg is not None and sw.unpack_command(msg).counts == (wp,) * 6
    assert st.catch_ups == 2


def test_servo_agent_does_not_distrust_a_whole_host_stall():
    """A stall of the whole host stops the servo too (its tick barely moves): the agent's
    late cycle trusts the report, as before (the servo judges the stall by its own queue)."""
    cmd = MemoryDatabase("ctrl_command", L.CTRL_COMMAND_LAYOUT)
    status = MemoryDatabase("ctrl_status", L.CTRL_STATUS_LAYOUT)
    cmd.update(link_alive=1, cmd_mode=L.JOG_MODE, cmd_id=0)
    st = ServoAgentStation(ServoAgentCore(), cmd, status, command_hz=60.0)
    st.take(report(tick=8), 10**9)
    assert st.cycle(10**9 + P) is not None
    st.take(report(tick=20), 10**9 + 12 * P)  # 11 periods of stall, the servo ticked 12 times
    assert st.cycle(10**9 + 12 * P, late_ns=10 * P) is not None
    assert st.catch_ups == 0


def test_agent_station_copies_replies_and_declares_a_silent_link_dead():
    brain_cmd = MemoryDatabase("command", L.ARM_COMMAND_LAYOUT)
    ctrl_cmd = MemoryDatabase("ctrl_command", L.CTRL_COMMAND_LAYOUT)
    status = MemoryDatabase("ctrl_status", L.CTRL_STATUS_LAYOUT)
    agent = AgentStation(status, ctrl_cmd, P, 3)
    cid = arm_command.joint(brain_cmd, [1, 2, 3, 4, 5, 6], 90)
    reply = agent.on_command(brain_cmd.raw_bytes(), 10, 0)
    c = ctrl_cmd.read()
    assert list(c["encoder_cmd_ext"]) == [1, 2, 3, 4, 5, 6] and int(c["joint_time_count"]) == 90
    assert int(c["cmd_id"]) == cid and int(c["brain_tick"]) == 10 and int(c["link_alive"]) == 1
    assert reply == status.raw_bytes()
    assert agent.on_timer(2 * P) is None and int(ctrl_cmd.read()["link_alive"]) == 1
    assert agent.on_timer(3 * P) == 13  # dead: local ticks follow time
    assert int(ctrl_cmd.read()["link_alive"]) == 0 and int(status.read()["fault"]) & L.FAULT_LINK
    assert int(ctrl_cmd.read()["brain_tick"]) == 13
    agent.on_command(brain_cmd.raw_bytes(), 14, 4 * P)
    assert not int(status.read()["fault"]) & L.FAULT_LINK and int(ctrl_cmd.read()["link_alive"]) == 1


def test_remote_station_translates_acknowledges_and_marks_a_silent_agent_stale():
    brain_status = MemoryDatabase("status", L.ARM_STATUS_LAYOUT)
    brain_cmd = MemoryDatabase("command", L.ARM_COMMAND_LAYOUT)
    ctrl_status = MemoryDatabase("ctrl_status", L.CTRL_STATUS_LAYOUT)
    T = np.eye(4)
    T[:3, 3] = (100.0, 200.0, 300.0)
    remote = RemoteStation(brain_status, brain_cmd, StatusTranslator("arm1", ARM6R, lambda counts: T), 3)
    cid = arm_command.home(brain_cmd)
    remote.on_tick(1)
    assert remote.command_payload() == brain_cmd.raw_bytes()
    ctrl_status.update(homed=L.HOMED, busy=4, cmd_id=cid, encoder_pos=[7] * 6)
    assert remote.on_reply(1, ctrl_status.raw_bytes(), 123)
    s = brain_status.read()
    assert int(s["busy"]) == 4 and int(s["cmd_id"]) == cid and float(s["z"]) == 300.0
    assert int(s["updated_ns"]) == 123 and int(s["tick"]) == 1 and int(s["stale"]) == 0
    assert int(brain_cmd.read()["sent"]) == 0  # the agent acknowledged that very command
    for tick in range(2, 6):
        remote.on_tick(tick)
    assert int(brain_status.read()["stale"]) == 1 and int(brain_status.read()["fault"]) & L.FAULT_LINK


def test_remote_station_marks_a_silent_heartbeat_and_clears_it_on_the_next_tick():
    """The heartbeat-silence rule lives in the station (issue 25 item 3), fed virtual time here."""
    brain_status = MemoryDatabase("status", L.ARM_STATUS_LAYOUT)
    ctrl_status = MemoryDatabase("ctrl_status", L.CTRL_STATUS_LAYOUT)
    remote = RemoteStation(brain_status, None, StatusTranslator("arm1", ARM6R, lambda counts: np.eye(4)), 3,
                           heartbeat_hz=60.0)
    period = int(round(1e9 / 60))  # [ns]
    t = 0
    for tick in range(1, 5):  # ticks and replies on time: never silent
        t = tick * period
        assert not remote.on_poll(t)
        remote.on_tick(tick, t)
        remote.on_reply(tick, ctrl_status.raw_bytes(), t)
    assert int(brain_status.read()["stale"]) == 0
    assert not remote.on_poll(t + 3 * period)  # 3 periods of silence: not yet
    assert remote.on_poll(t + 3 * period + 1)  # past stale_ticks periods: once
    assert not remote.on_poll(t + 10 * period)
    s = brain_status.read()
    assert int(s["stale"]) == 1 and int(s["fault"]) & L.FAULT_HEARTBEAT and int(s["fault"]) & L.FAULT_LINK
    remote.on_tick(5, t + 11 * period)  # the heartbeat is back: FAULT_HEARTBEAT cleared ...
    assert not int(brain_status.read()["fault"]) & L.FAULT_HEARTBEAT
    assert int(brain_status.read()["stale"]) == 1  # ... and the next reply clears stale
    remote.on_reply(5, ctrl_status.raw_bytes(), t + 11 * period)
    assert int(brain_status.read()["stale"]) == 0


def test_arm_commands_are_in_heartbeat_ticks():
    cmd = MemoryDatabase("command", L.ARM_COMMAND_LAYOUT)
    assert arm_command.ticks_for(1.5, 60.0) == 90
    arm_command.cart(cmd, np.eye(4), 45)
    c = cmd.read()
    assert int(c["cart_time_count"]) == 45 and int(c["coord"]) == L.CARTSPACE and int(c["sent"]) == 1
    arm_command.stop(cmd)
    assert int(cmd.read()["joint_time_count"]) == L.STOP_TICKS == int(cmd.read()["cart_time_count"])


def test_the_shells_and_lockstep_call_the_same_stations():
    """Each cycle is written once: the real-time program builds its station, LockstepArm (with its
    ArmChain) builds the same ones and keeps no copy of a shell's rules (field lists, fault sets, freshness)."""
    import inspect

    from droid.brain.runtime import remote
    from droid.sim import arm_chain
    from droid.sim.reis import cell
    from droid.subunits import agent
    from droid.arm import planner
    from droid.subunits.reis import servo_agent, servo_prog, watchdog_prog

    shells = {servo_prog: "ServoStation(", watchdog_prog: "WatchdogStation(", servo_agent: "ServoAgentStation(",
              planner: "PlannerStation(", agent: "AgentStation(", remote: "RemoteStation("}
    lockstep = inspect.getsource(cell) + inspect.getsource(arm_chain)  # the Reis's stations + the Brain side
    for module, station in shells.items():
        main = inspect.getsource(module)[inspect.getsource(module).index("def main"):]
        if module is agent:  # its shell: the program and the subunit it serves (one or several)
            main = inspect.getsource(agent.agent_main) + inspect.getsource(agent._AgentServed)
        assert station in main, module.__name__
        assert station in lockstep, station
    for copy in ("MY_FAULTS", "COMMAND_MAP", "copy_fields", '"encoder_cmd", "busy"', "3e9", "STATUS_EVERY_TICKS",
                 "unpack_status", "pack_command", "counts_to_joints(np.asarray(st"):
        assert copy not in lockstep, copy


def test_servo_status_snapshot_is_what_its_properties_say():
    """ServoCore.status (every 4th tick; issue 28 item 2 subtracts the counts as Python ints) gives
    the fields its properties give, as Python ints, unhomed or homed, before and after a reading."""
    from droid.kinematics import load_robot
    from droid.subunits.reis.servo import ServoStatus

    core = ServoCore(ServoParams.from_robot(load_robot("reis_v15")))
    rng = np.random.default_rng(28)
    for i in range(300):
        if i:
            core._pos = None if i % 7 == 0 else rng.integers(-10**9, 10**9, 6)
            core._target = rng.integers(-10**9, 10**9, 6)
            core._zero = None if i % 3 == 0 else rng.integers(-10**9, 10**9, 6)
        want = ServoStatus(tick=core.tick, mode=core.mode, homed=core.homed,
                           homing_joint=-1 if core.homing_joint is None else core.homing_joint,
                           starved=core.starved, braking=core.braking, fault=core.fault,
                           encoder_pos=core.encoder_pos, encoder_cmd=core.encoder_cmd,
                           following_error=core.following_error, dac=core.dac)
        got = core.status()
        assert got == want
        assert all(type(v) is int for v in got.encoder_pos + got.encoder_cmd + got.following_error)


def test_servo_status_message_is_the_packed_snapshot():
    """ServoCore.status_message (droid-servo's and every lockstep trial's status message, issue 44)
    gives the very bytes of pack_status(status()), unhomed or homed, huge counts clipped alike,
    with and without the amplifiers, and after real ticks (homing included)."""
    from droid.kinematics import load_robot

    core = ServoCore(ServoParams.from_robot(load_robot("reis_v15")))
    rng = np.random.default_rng(44)
    for i in range(300):
        if i:
            core._pos = None if i % 7 == 0 else rng.integers(-10**10 if i % 5 == 0 else -10**9, 10**9, 6)
            core._target = rng.integers(-10**9, 10**10 if i % 11 == 0 else 10**9, 6)
            core._zero = None if i % 3 == 0 else rng.integers(-10**9, 10**9, 6)
        for amps in (True, False):
            assert core.status_message(amps) == sw.pack_status(core.status(), amps)
    core = ServoCore(ServoParams.from_robot(load_robot("reis_v15")))
    raw = [1000, 2000, 3000, 4000, 5000, 6000]
    for i in range(200):
        if i == 3:
            core.command(Mode.HOME)
        raw = [(r + int(d)) % 65536 for r, d in zip(raw, rng.integers(-40, 40, 6))]
        core.step(raw, [i % 2 == 0] * 6)
        assert core.status_message(True) == sw.pack_status(core.status(), True)


def test_remote_reply_as_byte_ranges_writes_the_record_the_field_update_writes():
    """The arm's reply copies its fields as byte ranges (issue 44) where both records hold them at
    the same offsets and dtypes, and writes tick, updated_ns, stale and the pose as two struct packs
    (``_reply_packers``): the Brain Status afterwards is byte for byte what the field-wise ``update``
    leaves -- and what the byte ranges with numpy's field assignments leave -- homed or not, pose
    and seq included, over random replies."""
    from droid.kinematics import load_robot

    model = load_robot("reis_v15")
    fk = lambda counts: model.fk(model.gearing.counts_to_joints(np.asarray(counts, float)))  # noqa: E731
    rng = np.random.default_rng(44)
    stations = []
    for how in ("packed", "bytewise", "fields"):
        status, cmd = MemoryDatabase("status", L.ARM_STATUS_LAYOUT), MemoryDatabase("command", L.ARM_COMMAND_LAYOUT)
        st = RemoteStation(status, cmd, StatusTranslator("arm1", ARM6R, fk), 3)
        if how != "packed":
            st._pack = None
        if how == "fields":
            st._runs = None
        stations.append((st, status, cmd))
    assert stations[0][0]._runs and len(stations[0][0]._runs) == 2  # encoder_pos .. homed, fault .. cmd_result
    assert stations[0][0]._pack is not None  # the Brain's arm Status holds the packs' fields side by side
    ctrl = MemoryDatabase("ctrl_status", L.CTRL_STATUS_LAYOUT)
    for tick in range(1, 80):
        ctrl.update(homed=L.HOMED if tick % 9 else 0, busy=int(rng.integers(0, 5)), cmd_id=int(rng.integers(0, 2**32)),
                    fault=int(rng.integers(0, 2**32)), cmd_result=int(rng.integers(-3, 3)),
                    encoder_pos=rng.integers(-10**6, 10**6, 6) if tick % 3 else [5] * 6,
                    encoder_cmd=rng.integers(-2**31, 2**31, 6), cmd_mode=int(rng.integers(0, 4)), coord=tick % 2)
        for st, status, cmd in stations:
            if tick % 5 == 0:
                arm_command.home(cmd)
            st.on_tick(tick)
            st.command_payload()
            assert st.on_reply(tick, ctrl.raw_bytes(), 1000 * tick)
        for other in stations[1:]:
            assert stations[0][1].raw_bytes() == other[1].raw_bytes(), tick
            assert stations[0][2].raw_bytes() == other[2].raw_bytes(), tick
    assert int(stations[0][1].read()["tick"]) == 79 and float(stations[0][1].read()["x"]) != 0.0
