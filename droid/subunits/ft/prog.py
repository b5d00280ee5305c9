"""droid-ft SUBUNIT: a six-axis force/torque sensor into its subunit's Status (thesis §7.3).

"Force/torque sensors ... could be used on any of the two robots through the
standard interface" (§7): the sensor is a subunit of class ``ft6`` like any
other.  This program reads the calibration page of the device named by the
subunit's ``device`` URL (:mod:`droid.subunits.ft.rdt`), asks it for
real-time RDT streaming, and ``rate_hz`` times a second (the URL's) checks
every record that arrived and writes the newest into its ``ctrl_status``
(``ft6_status``): force and torque in the sensor frame [N, N m], the same
wrench in the tool frame (``sensor_tool_pose``: the tool frame in the sensor frame,
x y z mm, A B C ZYZ deg), the record's sequence numbers and status word, and
the counters.  ``droid-agent`` serves that record to the Brain's
``droid-remote``, which copies it into the Brain's Status (``droid-snoop``).

The stale rule is the cell's (``stale_ticks`` heartbeat periods, as every
link applies it): no record for that long makes ``valid = 0``, ``stale = 1``
and the DEVICE fault, and the start request is sent again every
``RESTART_S`` (the device may have restarted); so does a calibration page
that cannot be read (one line on stderr per new reason; retried every
``RESTART_S``).  A reading is never scaled without a calibration.

Cell file::

    [subunits.ft]
    class = "ft6"
    host = "arm1"
    device = "netft://127.0.0.1:49152?rate_hz=100&http_port=8049"
    sensor_tool_pose = [0.0, 0.0, 150.0, 0.0, 0.0, 0.0]   # tool frame in the sensor frame (mm, ZYZ deg)
    programs = ["droid-ft", "droid-agent"]
"""
from __future__ import annotations

import sys
import time
from dataclasses import dataclass

import numpy as np

from droid.brain.db.databases import open_local
from droid.brain.db.layouts import FAULT_DEVICE, FAULT_FORCE
from droid.brain.runtime.program import Presence, Stop, close_all, notify_ready, presence_key, subunit_program
from droid.brain.runtime.rt import PeriodicTimer, try_sched_fifo
from droid.cli import BadInput, run
from droid.kinematics.transforms import pose_to_T
from droid.numbers import POSE
from droid.brain.cell.registry import open_url
from droid.subunits.ft.rdt import STATUS_SATURATION, Calibration, CalibrationError, NetFtDevice, Record

PROG = "droid-ft"
#: how often a silent device is asked to stream again, and a missing calibration fetched again [s]
RESTART_S = 0.5
U32 = 0xFFFFFFFF


@dataclass(frozen=True)
class FtOptions:
    url: str
    T_sensor_tool: np.ndarray  # 4x4, mm
    guard_arm: str | None = None  # the arm the sensor sits on, whose Status gets FAULT_FORCE


def ft_options(sub, cell=None) -> FtOptions:
    """(device URL, the tool frame in the sensor frame, the guarded arm) of an ft6 subunit of
    ``cell`` (needed for ``guard_arm``); BadInput names the key."""
    where = f"[subunits.{sub.name}]"
    sub.check_class("ft6", "an ft6 force/torque sensor")
    url = sub.device_url("an ft6 sensor", "netft://192.168.1.1:49152")
    pose = sub.options.get("sensor_tool_pose", [0.0] * 6)
    if not isinstance(pose, list) or len(pose) != 6:
        raise BadInput(f"{where} sensor_tool_pose must be 6 numbers: x y z [mm] A B C [ZYZ deg]")
    try:
        vals = [rng.check(v, f"{where} sensor_tool_pose[{i}]") for i, (v, rng) in enumerate(zip(pose, POSE))]
    except ValueError as exc:
        raise BadInput(str(exc)) from None
    unknown = sorted(set(sub.options) - {"device", "sensor_tool_pose", "guard_arm"})
    if unknown:
        raise BadInput(f"{where} unknown key(s) for an ft6 sensor: {', '.join(unknown)}")
    guard_arm = sub.options.get("guard_arm")
    if guard_arm is not None:
        subs = cell.subunits if cell is not None else {}
        if not isinstance(guard_arm, str) or guard_arm not in subs:
            raise BadInput(f"{where} guard_arm must name an arm subunit of the cell, got {guard_arm!r}")
        arm = subs[guard_arm]
        if not arm.kind.kinematic or "ctrl_status" not in arm.kind.local:
            raise BadInput(f"{where} guard_arm {guard_arm!r} is a {arm.cls} subunit, not an arm")
        if arm.host != sub.host:
            raise BadInput(f"{where} guard_arm {guard_arm!r} runs on host {arm.host!r}, the sensor on "
                           f"{sub.host!r}: the guard writes the arm's own Status, on the same host")
        if "droid-planner" not in arm.programs:  # a guard nobody acts on would be a silent one
            raise BadInput(f"{where} guard_arm {guard_arm!r} runs no droid-planner: only the planner "
                           f"ends a move on FAULT_FORCE")
    return FtOptions(url, pose_to_T(*vals), guard_arm)


def wrench_in_tool(force_N, torque_Nm, T_sensor_tool) -> tuple[np.ndarray, np.ndarray]:
    """A wrench measured at the sensor origin (sensor frame) -> about the tool origin, in the
    tool frame: f_T = R^T f, m_T = R^T (m - p x f), p the tool origin in the sensor frame [m]."""
    R = T_sensor_tool[:3, :3]
    p_m = T_sensor_tool[:3, 3] * 1e-3
    f = np.asarray(force_N, float)
    m = np.asarray(torque_Nm, float)
    return R.T @ f, R.T @ (m - np.cross(p_m, f))


class FtCore:
    """droid-ft's cycle without I/O: records (checked by the driver's RdtStream), the calibration
    and the time in, the ctrl_status fields out.  Times [ns] are the caller's clock."""

    def __init__(self, T_sensor_tool: np.ndarray, stale_ns: int) -> None:
        self.T_sensor_tool = np.asarray(T_sensor_tool, float)
        self.stale_ns = int(stale_ns)
        self.last: Record | None = None
        self.last_ns: int | None = None  # when the newest record arrived
        self.force_N = np.zeros(3)
        self.torque_Nm = np.zeros(3)

    def on_records(self, records: list[Record], calib: Calibration | None, now_ns: int) -> None:
        if not records or calib is None:
            return
        self.last = records[-1]
        self.last_ns = now_ns
        c = self.last.counts
        self.force_N = np.array(c[:3], float) * calib.n_per_count
        self.torque_Nm = np.array(c[3:], float) * calib.nm_per_count

    def silent(self, now_ns: int) -> bool:
        """No record for the stale rule's span (or none yet)."""
        return self.last_ns is None or now_ns - self.last_ns >= self.stale_ns

    def fields(self, dev_stream, calib: Calibration | None, biased: bool, now_ns: int) -> dict:
        silent = self.silent(now_ns)
        valid = calib is not None and not silent
        f_t, m_t = wrench_in_tool(self.force_N, self.torque_Nm, self.T_sensor_tool)
        rec = self.last
        return dict(
            force_N=self.force_N, torque_Nm=self.torque_Nm, force_tool_N=f_t, torque_tool_Nm=m_t,
            sample_ns=self.last_ns or 0,
            sample_age_ms=(now_ns - self.last_ns) / 1e6 if self.last_ns is not None else 0.0,
            updated_ns=now_ns,
            rdt_seq=rec.rdt_seq if rec else 0, ft_seq=rec.ft_seq if rec else 0,
            status_word=rec.status if rec else 0,
            valid=int(valid), saturated=int(bool(rec and rec.status & STATUS_SATURATION)), biased=int(biased),
            dropped=dev_stream.dropped & U32, out_of_order=dev_stream.out_of_order & U32,
            bad_datagrams=dev_stream.bad_datagrams & U32, records=dev_stream.records & U32,
            stale=int(silent), fault=0 if valid else FAULT_DEVICE,
        )


class FtCommandRule:
    """The sensor's Command (``ft6_ctrl_command``, copied in by droid-agent from the Brain):

    * a ``bias_id`` other than the last one seen asks the device to bias once (RDT's set-bias:
      it subtracts its present reading from every later one) -- a task tares the sensor so,
      through the Brain, the way droid-contact takes the torch's weight out before it touches;
    * ``guard_force_n`` > 0 arms the **over-force guard** (thesis §7.3's force control needs
      one beside the arm, not behind the Brain's two 60 Hz exchanges): while the sensor reads
      |F| above it -- or cannot be read at all -- :meth:`over` is True, and stays True (a latch)
      until the limit changes; droid-ft sets FAULT_FORCE in the Status of the arm it sits on
      (``guard_arm``, same host), so that arm's planner ends its move within its next tick.
      0 disarms it.

    The ``bias_id`` present when the program starts is not replayed (as commands issued
    before an agent starts are not)."""

    def __init__(self) -> None:
        self.bias_id: int | None = None
        self.limit_n = 0.0  # [N]; 0 = off
        self.latched = False  # tripped since the limit was set
        self.biases = 0  # bias requests taken

    def take(self, cmd) -> bool:
        """Read one Command record; True when it asks for a bias now."""
        bid = int(cmd["bias_id"])
        ask = self.bias_id is not None and bid != self.bias_id
        self.bias_id = bid
        limit = float(cmd["guard_force_n"])
        limit = limit if np.isfinite(limit) and limit > 0 else 0.0
        if limit != self.limit_n:  # re-armed at another limit, or disarmed: the latch opens
            self.latched = False
        self.limit_n = limit
        self.biases += ask
        return ask

    def over(self, fields: dict) -> bool:
        """The guard trips: armed, and the reading is above the limit or not valid.  It latches:
        an arm pressing at the limit reads just above and just below it from sample to sample,
        and each dip would let the planner take the task's next step deeper.  Only a new limit
        (or 0) opens it."""
        if self.limit_n <= 0:
            return False
        if not self.latched:
            self.latched = not fields["valid"] or float(np.linalg.norm(fields["force_N"])) > self.limit_n
        return self.latched


class FtStation:
    """The program's cycle with its driver (the shell only keeps time and writes the record):
    calibrate and start, read everything waiting, restart a silent stream, bias once if asked."""

    def __init__(self, dev: NetFtDevice, core: FtCore, restart_ns: int, log=None) -> None:
        self.dev = dev
        self.core = core
        self.restart_ns = restart_ns
        self.log = log or (lambda line: print(f"{PROG}: {line}", file=sys.stderr, flush=True))
        self._calibrate_at = -1 << 62  # when to fetch a missing calibration next [ns]
        self._start_at = -1 << 62  # when a silent stream may be asked again [ns]
        self._said = ""
        self._bias_pending = dev.url.bias
        self.rule = FtCommandRule()

    def _say(self, line: str) -> None:
        if line != self._said:  # one line per new reason, not one per retry
            self._said = line
            self.log(line)

    def step(self, now_ns: int, command=None) -> dict:
        """One cycle at ``now_ns`` [ns]; ``command``: the sensor's Command record (or None),
        read by :attr:`rule` (a bias it asks for is sent once records flow)."""
        dev = self.dev
        if command is not None and self.rule.take(command):
            self._bias_pending = True
        if dev.calibration is None and now_ns >= self._calibrate_at:
            self._calibrate_at = now_ns + self.restart_ns
            try:
                cal = dev.calibrate()
                self._say(f"calibration: {cal.counts_per_force:g} counts/{cal.force_unit}, "
                          f"{cal.counts_per_torque:g} counts/{cal.torque_unit}")
            except CalibrationError as exc:
                self._say(f"{exc}; retrying every {RESTART_S:g} s")
        records = dev.poll()
        self.core.on_records(records, dev.calibration, now_ns)
        if records:
            self._start_at = now_ns  # a silence from now on asks again at once
        if dev.calibration is not None and self.core.silent(now_ns) and now_ns >= self._start_at:
            dev.start()  # the first time, or records stopped: ask (again) every RESTART_S
            self._start_at = now_ns + self.restart_ns
            self._bias_pending = self._bias_pending or dev.url.bias
        if records and self._bias_pending:
            self._bias_pending = not dev.bias()
        if dev.last_error:
            self._say(dev.last_error)
            dev.last_error = ""
        return self.core.fields(dev.stream, dev.calibration, dev.biased, now_ns)


def set_guard_fault(arm_status, over: bool) -> None:
    """FAULT_FORCE in the guarded arm's own Status (its other bits kept; every program of the
    arm masks its own bits the same way)."""
    with arm_status.locked() as st:
        st["fault"] = (int(st["fault"]) & ~FAULT_FORCE) | (FAULT_FORCE if over else 0)
        arm_status.mark_written()


class FtGuard:
    """The over-force guard's shell (thesis §7.3; droid-ft's loop and lockstep's alike): each
    cycle's fields through :attr:`rule` (:class:`FtCommandRule`), FAULT_FORCE set or cleared in
    the guarded arm's Status (``arm_status``, its ``ctrl_status``; None: no guard) when the
    verdict changes, with one line naming the arm, |F| [N] and the limit [N]."""

    def __init__(self, rule: FtCommandRule, arm_status, arm_name: str | None, sub_name: str, log) -> None:
        self.rule, self.arm_status, self.arm_name, self.sub_name, self.log = rule, arm_status, arm_name, sub_name, log
        self.tripped = False
        self.trips = 0  # times it tripped

    def step(self, fields: dict) -> bool:
        """The verdict on one cycle's ``fields`` (True: tripped, FAULT_FORCE set)."""
        over = self.rule.over(fields)
        if over != self.tripped and self.arm_status is not None:
            set_guard_fault(self.arm_status, over)
            self.trips += over
            f = float(np.linalg.norm(fields["force_N"]))
            self.log(f"{self.sub_name}: over-force guard {'tripped' if over else 'clear'} on {self.arm_name}: "
                     f"|F| {f:.1f} N, limit {self.rule.limit_n:g} N{'' if fields['valid'] else ' (no valid reading)'}")
        self.tripped = over
        return over

    def release(self) -> None:
        """A clean stop: FAULT_FORCE cleared if this guard set it (a restart re-reads the guard at once)."""
        if self.tripped and self.arm_status is not None:
            set_guard_fault(self.arm_status, False)
        self.tripped = False


@run
def main(argv=None) -> int:
    args, cell, sub = subunit_program(PROG, "Read a force/torque sensor (ATI Net F/T, RDT) into its "
                                      "subunit's Status.", argv, example="ft")
    opts = ft_options(sub, cell)
    dev = open_url(opts.url, "ft")  # droid.subunits.ft.rdt.open_ft, by the registry
    try_sched_fifo(wanted=cell.sched_fifo, prog=PROG)  # the guard is real-time (after bad input is refused)
    status = open_local(cell, sub, "ctrl_status")
    command = open_local(cell, sub, "ctrl_command")
    arm_status = open_local(cell, cell.subunit(opts.guard_arm), "ctrl_status") if opts.guard_arm else None
    presence = Presence(cell.name, presence_key(PROG, sub.name), f"{PROG} {sub.name}")
    timer = PeriodicTimer(int(round(1e9 / dev.url.rate_hz)))
    station = FtStation(dev, FtCore(opts.T_sensor_tool, cell.stale_ticks * cell.period_ns), int(RESTART_S * 1e9))
    guard = FtGuard(station.rule, arm_status, opts.guard_arm, sub.name,
                    lambda line: print(f"{PROG} {line}", file=sys.stderr, flush=True))
    cycles = 0
    try:
        status.update(**station.step(time.monotonic_ns(), command.read()))
        presence.ready()
        notify_ready(args.ready_fd)
        while not Stop.requested:
            if not timer.wait(0.5):
                continue
            cycles += 1
            fields = station.step(time.monotonic_ns(), command.read())
            status.update(**fields)
            guard.step(fields)
            presence.beat(0, cycles, timer.overruns, timer.lateness_max_ns, bad_frames=dev.stream.bad_datagrams)
    finally:
        guard.release()
        if arm_status is not None:
            arm_status.close()
        close_all(dev, timer, command, status, presence)
    return 0

if __name__ == "__main__":
    sys.exit(main())
