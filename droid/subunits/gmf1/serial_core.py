"""The core of droid-gmf1-serial (thesis §4.2.4): newest command only, over a 9600-baud line.

Thesis: the serial program "waits for a relay message from the GMF1Agent
program ...  copies the contents [of the Command shared memory] into a local
cache ... converted into global translations and Euler rotation angles ...
sent to the KAREL Serial Server as ASCII characters separated by whitespaces";
the KAREL server cycles at 6 Hz, "hence, the Serial program must ignore the
other 9 commands and only send the most recent command set to the Fanuc
controller once it has completed its previous move."

:class:`SerialCore` is that program without I/O: once per relayed heartbeat
tick, :meth:`SerialCore.step` takes the controller's Command record (a
:class:`CommandSnapshot`), what it needs of the Status record (homed, encoder
positions), the bytes read from the port since the last tick and whether the
port is open; it returns the bytes to write, the Status fields to write, the
FAULT_DEVICE level and whether the shell should (re)open or close the port.
Time is counted in ticks.

Commands (a new command = a new ``cmd_id``):

* NORMAL + CARTSPACE: the pose (global frame, Table 3.2) is taken into the
  robot's base frame with the subunit's ``base`` pose and sent as
  ``MOVE id x y z a b c t`` (mm, ZYZ deg; t = cart_time_count ticks in s);
* NORMAL + JSPACE: encoder counts relative to home -> joint angles through the
  model's gearing -> ``JMOVE id j1..j6 t``;
* HOME_MODE: ``HOME id``; Status.homed is cleared when it is sent and set again
  by droid-gmf1-encoder once the move is done and the cards are zeroed;
* JOG_MODE is refused (CMD_REFUSED): the KAREL server cannot jog at 60 Hz;
* before homing, NORMAL commands are refused (CMD_REFUSED) and nothing moves;
  so are targets outside the workspace or the joint limits (checked with the
  model's IK and pick, the same as the controller's).

The first tick (a start or a restart): a command is executed or refused, never
lost (Tables 3.1-3.2: ``sent``, ``cmd_id``, ``cmd_result``, ``busy``).  The
command found then is not replayed only if Status already answers it
(:attr:`StatusView.cmd_id`: an earlier run sent, refused or stopped it) or
there is none (cmd_id 0); any other — written before our first relayed tick,
or held pending by a run that died — is taken like a new one.

Stop (a NORMAL command with STOP_TICKS, written by a task that gave up): the
pending command is dropped and nothing new is sent; a move already sent runs to
its end (the KAREL server has no abort).

Protective stop (issue 41): while the Status has FAULT_COLLISION (the collision guard's stop) or
FAULT_GUARD (the guard of a cell that declares one is silent: droid.guard.gate), a NORMAL move in
flight is halted -- ``HALT id``, sent at once, ends it along its path at the controller's
deceleration -- and reported CMD_FAILED, and a NORMAL command waiting or arriving is refused
(CMD_REFUSED), as the Reis planner does; a stop or a HOME is still taken.

Drop policy: while a command is in flight (sent, not DONE) newer commands wait
as one *pending* command; a newer one replaces it and the replaced one is
counted in ``dropped`` (as are cmd_ids skipped between two ticks).  The pending
command is sent once the previous move is DONE and the interpreter's cycle has
passed: a line is written only if its last byte reaches the controller at
least one cycle (+ ``cycle_margin_s``) after the last byte of the previous
line, so the controller never sees more than ``cycle_hz`` lines a second.

Busy (Status.busy, heartbeat ticks): while a command is waiting or in flight,
the ticks left of its planned duration (the controller's ``ACK`` seconds; the
requested time until then), at least 1; 0 when idle.

Faults (FAULT_DEVICE, level): the port is not open; a request unanswered for
``reply_timeout_s``; a move not DONE ``done_margin_s`` (+25 %) after its planned
end (the command is then CMD_FAILED and busy drops to 0); a garbled reply
line.  The program then sends ``STAT`` probes; the fault clears at the first
good reply.  Three unanswered probes in a row close the port, which is
reopened with exponential back-off.  While the controller's state is unknown
no new motion is sent; a probe that says IDLE resolves an in-flight command
(its DONE was lost: OK; it never arrived: sent again — never if it was already
reported failed), one that says MOVING waits for it.  A command reported
failed that the controller finishes after all (a late DONE, or a probe naming
it) turns back to CMD_OK: Status says what the arm did.

Each BUSY answer widens the gap kept between lines by 50 ms (up to 1 s; every
ACK halves it), so a controller slower than its nominal cycle is not flooded.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from droid.brain.db.layouts import (CARTSPACE, CMD_FAILED, CMD_OK, CMD_REFUSED, FAULT_COLLISION, FAULT_GUARD, HOME_MODE,
                                 JSPACE, NORMAL_MODE, OFF, STOP_TICKS)
from droid.kinematics import RobotModel, Unreachable
from droid.kinematics.transforms import T_to_pose, inv_homo, record_pose
from droid.subunits.gmf1 import karel_wire as kw

# core states
CLOSED = "closed"  # no port
PROBING = "probing"  # a STAT is out; the controller's state is unknown
IDLE = "idle"  # controller idle as far as we know
WAIT_ACK = "wait_ack"  # a motion request is out, no answer yet
MOVING = "moving"  # ACKed, waiting for DONE

PROBE_ID_BASE = 0xF0000000  # STAT probes use ids far above any cmd_id a task will reach
MAX_ID_GAP = 1_000_000  # larger cmd_id jumps are a restart, not dropped commands
MAX_RETRIES = 60  # BUSY/ERR answers to one command before it fails (~10 s at 6 Hz)
PROBES_BEFORE_REOPEN = 3
BUSY_BACKOFF_S = 0.05  # each BUSY answer widens the gap kept between lines by this much ...
BUSY_BACKOFF_MAX_S = 1.0  # ... up to this; every ACK halves the extra gap again


@dataclass(frozen=True)
class SerialParams:
    """Timing of the serial program (seconds; converted to ticks with the heartbeat period)."""

    period_s: float = 1.0 / 60.0
    baud: int = kw.BAUD
    cycle_hz: float = 6.0  # the KAREL interpreter's cycle (thesis §4.2.4)
    reply_timeout_s: float = 1.0
    done_margin_s: float = 1.0
    done_margin_frac: float = 0.25
    probe_interval_s: float = 1.0
    cycle_margin_s: float = 0.01  # slack on the interpreter's cycle (wake-up jitter, world step)
    reopen_min_s: float = 0.1
    reopen_max_s: float = 2.0

    def ticks(self, seconds: float) -> int:
        return max(1, math.ceil(seconds / self.period_s - 1e-9))


@dataclass(frozen=True)
class CommandSnapshot:
    """What the serial program reads from the controller's Command record (Table 4.3)."""

    cmd_id: int
    cmd_mode: int
    coord: int
    T: np.ndarray  # 4x4 wrist-centre pose [mm] in the global frame
    cart_ticks: int
    joint_ticks: int
    encoder_cmd_ext: np.ndarray  # joint target [counts wrt home]
    link_alive: bool = True


def is_stop(cmd: CommandSnapshot) -> bool:
    """A NORMAL command whose time count is STOP_TICKS (layouts: a task gave up)."""
    ticks = cmd.joint_ticks if cmd.coord == JSPACE else cmd.cart_ticks
    return cmd.cmd_mode == NORMAL_MODE and ticks == STOP_TICKS


def snapshot_command(rec) -> CommandSnapshot:
    """A :class:`CommandSnapshot` of a CTRL_COMMAND record."""
    return CommandSnapshot(int(rec["cmd_id"]), int(rec["cmd_mode"]), int(rec["coord"]), record_pose(rec),
                           int(rec["cart_time_count"]), int(rec["joint_time_count"]),
                           np.array(rec["encoder_cmd_ext"], np.int64), bool(int(rec["link_alive"])))


@dataclass(frozen=True)
class StatusView:
    """What the serial program reads from the Status record."""

    homed: bool
    encoder_pos: np.ndarray  # [counts wrt home]
    cmd_id: int | None = None  # the last command answered (sent, refused, stopped); None: not known
    fault: int = 0  # the Status's FAULT_* bits (FAULT_COLLISION, FAULT_GUARD: the protective stop)


@dataclass
class SerialOut:
    """One step's outputs."""

    tx: bytes = b""
    open_port: bool = False
    close_port: bool = False
    fault: bool = False  # FAULT_DEVICE level asserted by this program
    fields: dict = field(default_factory=dict)  # Status fields to write


@dataclass
class _Flight:
    cmd: CommandSnapshot
    verb: str
    sent_tick: int
    want_ticks: int  # requested duration [ticks]
    ack_tick: int = 0
    planned_ticks: int = 0
    deadline: int = 0
    retries: int = 0
    failed: bool = False  # declared CMD_FAILED (timeout); the controller may still finish it
    halted: bool = False  # HALT sent (the protective stop): CMD_FAILED, whatever DONE says


class SerialCore:
    """See the module docstring.  ``model`` includes the subunit's base (global frame)."""

    def __init__(self, model: RobotModel, params: SerialParams | None = None) -> None:
        self.model = model
        self.p = params or SerialParams()
        self._base_inv = inv_homo(model.base)
        self.state = CLOSED
        self.rx = kw.LineSplitter()
        self.flight: _Flight | None = None
        self.pending: CommandSnapshot | None = None
        self.stops = 0  # stop commands taken (pending dropped)
        self.last_seen: int | None = None
        self.fault = True  # no port yet
        self.next_tx_tick = 0  # hold-off after a BUSY answer
        self._cycle_free_s = -1e9  # our last line's end + the interpreter's cycle [s, tick clock]
        self._extra_gap_s = 0.0  # learnt from BUSY answers: the controller is slower than its nominal cycle
        self.probe_id = 0
        self.probe_tick = 0
        self.probe_due = 0  # when to send the next probe (PROBING)
        self.probes_unanswered = 0
        self.need_probe = False  # a garbled line while idle: check the link
        self.reopen_tick = 0
        self.backoff_ticks = self.p.ticks(self.p.reopen_min_s)
        self.status = {"busy": 0}
        self._retries_of_pending = 0
        # counters (alike in shape only to each other and to the EGM twin's: one int per event counted)
        self.sent = 0
        self.completed = 0
        self.dropped = 0
        self.refused = 0
        self.failed = 0
        self.garbled = 0
        self.timeouts = 0
        self.busy_rejects = 0
        self.opens = 0
        self.unexpected = 0
        self.probes = 0
        self.late = 0  # commands reported failed that the controller finished after all
        self.halts = 0  # moves halted by the protective stop (HALT sent)
        self.stopping = False  # FAULT_COLLISION or FAULT_GUARD in the Status this tick

    # ------------------------------------------------------------------ step
    def step(self, tick: int, cmd: CommandSnapshot | None, st: StatusView, rx: bytes | None,
             port_open: bool) -> SerialOut:
        out = SerialOut()
        self.status = {}
        if not port_open:
            self._closed(tick, out)
        else:
            if self.state == CLOSED:
                self._opened(tick)
            garbled = self.garbled
            for line in self.rx.feed(rx or b""):
                self._reply(tick, line, st)
            if self.garbled != garbled:
                self.fault = True  # shown for at least this tick, even if good lines followed
            self._timeouts(tick, out)
        if cmd is not None:
            self._take_command(cmd, st)
        self.stopping = bool(st.fault & (FAULT_COLLISION | FAULT_GUARD))
        if self.stopping and port_open and self.state != CLOSED:
            self._halt(tick, out)
        if port_open and self.state != CLOSED:
            self._send(tick, st, out)
        self._busy(tick)
        out.fault = self.fault
        out.fields = self.status
        return out

    # ------------------------------------------------------------------ port
    def _closed(self, tick: int, out: SerialOut) -> None:
        if self.state != CLOSED:
            self.state = CLOSED
            self.fault = True
            self.rx.clear()
            self.reopen_tick = tick + self.backoff_ticks
            self.backoff_ticks = min(self.backoff_ticks * 2, self.p.ticks(self.p.reopen_max_s))
        f = self.flight
        if f is not None and not f.failed and tick > f.deadline:
            self.timeouts += 1
            self._fail(f)
        if tick >= self.reopen_tick:
            out.open_port = True
            self.reopen_tick = tick + self.backoff_ticks
            self.backoff_ticks = min(self.backoff_ticks * 2, self.p.ticks(self.p.reopen_max_s))

    def _opened(self, tick: int) -> None:
        self.opens += 1
        self.rx.clear()
        self.probes_unanswered = 0
        self._start_probe(tick, now=True)

    def _close(self, tick: int, out: SerialOut) -> None:
        out.close_port = True
        self.state = CLOSED
        self.fault = True
        self.rx.clear()
        self.reopen_tick = tick + self.backoff_ticks

    # ------------------------------------------------------------------ replies
    def _reply(self, tick: int, line: bytes, st: StatusView) -> None:
        try:
            r = kw.parse_reply(line)
        except kw.WireError:
            self.garbled += 1
            self.fault = True
            if self.state == IDLE:
                self.need_probe = True
            return
        # a well-formed reply: the controller and the line work
        self.fault = False
        self.probes_unanswered = 0
        self.backoff_ticks = self.p.ticks(self.p.reopen_min_s)
        f = self.flight
        if r.kind == kw.STAT:
            if self.state == PROBING and r.cmd_id == self.probe_id:
                self._probe_answer(tick, r)
            else:
                self.unexpected += 1
            return
        if self.state == PROBING and r.cmd_id == self.probe_id:
            if r.kind in (kw.BUSY, kw.ERR):  # the probe hit the interpreter's cycle: ask again soon
                self.probe_due = tick + self.p.ticks(1.0 / self.p.cycle_hz)
                self.probe_id = 0
            return
        if f is None or r.cmd_id != f.cmd.cmd_id:
            self.unexpected += 1
            return
        if r.kind == kw.ACK:
            if self.state in (WAIT_ACK, PROBING):
                self.state = MOVING
                f.ack_tick = tick
                self._extra_gap_s *= 0.5
                f.planned_ticks = int(math.ceil(r.seconds / self.p.period_s - 1e-9))
                f.deadline = tick + self._margin(f.planned_ticks)
        elif r.kind == kw.DONE:
            self._done(f)
            self.state = IDLE
        elif r.kind == kw.BUSY or (r.kind == kw.ERR and r.code != kw.ERR_RANGE):
            if r.kind == kw.BUSY:
                self.busy_rejects += 1
                self._extra_gap_s = min(self._extra_gap_s + BUSY_BACKOFF_S, BUSY_BACKOFF_MAX_S)
            self._retry(tick, f)
        elif r.kind == kw.ERR:  # RANGE: the controller cannot reach it
            self.refused += 1
            self.flight = None
            self.state = IDLE
            self.status.update(busy=0, cmd_result=CMD_REFUSED)

    def _margin(self, planned_ticks: int) -> int:
        return (planned_ticks + int(math.ceil(planned_ticks * self.p.done_margin_frac))
                + self.p.ticks(self.p.done_margin_s))

    def _done(self, f: _Flight) -> None:
        self.flight = None
        self.completed += 1
        self.status["busy"] = 0
        if f.halted:
            return  # the protective stop ended it: CMD_FAILED stands
        if f.failed:
            self.late += 1  # reported failed (too late), but it did complete: say so
        self.status["cmd_result"] = CMD_OK

    def _halt(self, tick: int, out: SerialOut) -> None:
        """The protective stop: HALT the NORMAL move in flight (once), CMD_FAILED; a waiting NORMAL
        command is refused (see the module docstring)."""
        p = self.pending
        if p is not None and p.cmd_mode == NORMAL_MODE:
            self.pending = None
            self.refused += 1
            self.status.update(cmd_id=p.cmd_id, cmd_result=CMD_REFUSED, busy=0, cmd_mode=p.cmd_mode, coord=p.coord)
        f = self.flight
        if f is None or f.halted or f.verb == kw.HOME or self.state not in (WAIT_ACK, MOVING):
            return
        f.halted = f.failed = True
        self.halts += 1
        self.failed += 1
        self.status.update(cmd_id=f.cmd.cmd_id, busy=0, cmd_result=CMD_FAILED)
        self._write(tick, kw.format_halt(f.cmd.cmd_id), out)

    def _fail(self, f: _Flight) -> None:
        f.failed = True
        self.failed += 1
        self.fault = True
        self.status.update(busy=0, cmd_result=CMD_FAILED)

    def _retry(self, tick: int, f: _Flight) -> None:
        """The controller did not take the command: send it again after a cycle (unless superseded)."""
        self.flight = None
        self.state = IDLE
        if f.failed:
            return  # the Brain was told it failed: never send it late
        f.retries += 1
        if f.retries > MAX_RETRIES:
            self._fail(f)
            return
        if self.pending is None:
            self.pending = f.cmd
            self._retries_of_pending = f.retries
        else:
            self.dropped += 1  # a newer command replaces the one the controller turned away
        self.next_tx_tick = max(self.next_tx_tick, tick + self.p.ticks(1.0 / self.p.cycle_hz))

    def _probe_answer(self, tick: int, r: kw.Reply) -> None:
        self.probe_id = 0
        f = self.flight
        if r.state == kw.MOVING:
            if f is not None and r.motion_id == f.cmd.cmd_id and not f.failed:
                self.state = MOVING  # our move is running (its ACK was lost or we reconnected)
                if f.deadline <= tick:
                    f.deadline = tick + self._margin(max(f.planned_ticks, f.want_ticks))
            else:  # a motion we gave up on, or one we do not know: ask again until it ends
                self._start_probe(tick)
            return
        # IDLE
        self.state = IDLE
        if f is not None:
            if r.motion_id == f.cmd.cmd_id:
                self._done(f)  # it ran; its DONE was lost
            else:
                self._retry(tick, f)  # it never arrived

    def _start_probe(self, tick: int, now: bool = False) -> None:
        self.state = PROBING
        self.probe_id = 0
        self.probe_due = tick if now else tick + self.p.ticks(self.p.probe_interval_s)

    # ------------------------------------------------------------------ timeouts
    def _timeouts(self, tick: int, out: SerialOut) -> None:
        f = self.flight
        rt = self.p.ticks(self.p.reply_timeout_s)
        if f is not None and not f.failed and tick > f.deadline:
            self.timeouts += 1
            self._fail(f)  # not DONE by its planned end + margin
            if self.state in (WAIT_ACK, MOVING):
                self._start_probe(tick, now=True)
        elif self.state == WAIT_ACK and f is not None and tick - f.sent_tick > rt:
            self.timeouts += 1
            self.fault = True
            self._start_probe(tick, now=True)
        if self.state == PROBING and self.probe_id and tick - self.probe_tick > rt:
            self.timeouts += 1
            self.fault = True
            self.probes_unanswered += 1
            self.probe_id = 0
            if self.probes_unanswered >= PROBES_BEFORE_REOPEN:
                self._close(tick, out)
                return
            self.probe_due = tick + self.p.ticks(self.p.probe_interval_s)

    # ------------------------------------------------------------------ commands
    def _take_command(self, cmd: CommandSnapshot, st: StatusView) -> None:
        if self.last_seen is None:
            # The first tick (a start, or a restart: droid-cell restart).  A command is either
            # executed or refused, and Status says which (Tables 3.1-3.2: cmd_id, cmd_result,
            # busy): the one found here was handled already only if Status answers it (an
            # earlier run of this program sent, refused or stopped it), or if there is none
            # (cmd_id 0: the safe start values, §4.1.4).  Any other was written before our
            # first tick (droid-home right after droid-cell up, before the relay's first tick
            # reached us) or while the previous run held it pending; the agent acknowledged
            # it ('sent' cleared), so dropping it here lost it silently: it is taken.
            handled = cmd.cmd_id == 0 or st.cmd_id is None or cmd.cmd_id == st.cmd_id
            self.last_seen = cmd.cmd_id
            if handled:
                return  # not replayed
        elif cmd.cmd_id == self.last_seen:
            return
        else:
            gap = (cmd.cmd_id - self.last_seen - 1) % (1 << 32)
            if gap < MAX_ID_GAP:
                self.dropped += gap
        self.last_seen = cmd.cmd_id
        if cmd.cmd_mode == OFF:
            return
        if self.pending is not None:
            self.dropped += 1  # superseded before it could be sent
        if is_stop(cmd):  # drop what waits; the KAREL server cannot abort a move in flight
            self.pending = None
            self.stops += 1
            self.status.update(cmd_id=cmd.cmd_id, cmd_result=CMD_OK, cmd_mode=cmd.cmd_mode, coord=cmd.coord)
            return
        self.pending = cmd

    def _send(self, tick: int, st: StatusView, out: SerialOut) -> None:
        if self.state == PROBING:
            if not self.probe_id and tick >= max(self.probe_due, self.next_tx_tick):
                probe_id = PROBE_ID_BASE + ((self.probes + 1) % 0x0FFFFFFF)
                line = kw.format_stat(probe_id)
                if self._may_send(tick, line):
                    self.probes += 1
                    self.probe_id = probe_id
                    self.probe_tick = tick
                    self._write(tick, line, out)
            return
        if self.state != IDLE or tick < self.next_tx_tick:
            return
        if self.pending is None:
            if self.need_probe:
                self.need_probe = False
                self._start_probe(tick, now=True)
                self._send(tick, st, out)
            return
        cmd = self.pending
        self.pending = None
        retries = self._retries_of_pending
        self._retries_of_pending = 0
        try:
            verb, line, want, target_counts = self._request(cmd, st)
        except _Refused:
            self.refused += 1
            self.status.update(cmd_id=cmd.cmd_id, cmd_result=CMD_REFUSED, busy=0, cmd_mode=cmd.cmd_mode,
                               coord=cmd.coord)
            return
        if not self._may_send(tick, line):  # the interpreter is still in the cycle of our last line
            self.pending = cmd
            self._retries_of_pending = retries
            return
        rt = self.p.ticks(self.p.reply_timeout_s)
        self.flight = _Flight(cmd, verb, tick, want, deadline=tick + rt + self._margin(want), retries=retries)
        self.state = WAIT_ACK
        self.sent += 1
        self.status.update(cmd_id=cmd.cmd_id, cmd_result=CMD_OK, cmd_mode=cmd.cmd_mode, coord=cmd.coord)
        if target_counts is not None:
            self.status["encoder_cmd"] = target_counts
        if verb == kw.HOME:
            self.status["homed"] = 0
            self.status["encoder_cmd"] = np.zeros(6, np.int32)
        self._write(tick, line, out)

    def _wire_s(self, line: bytes) -> float:
        return len(line) * kw.BITS_PER_BYTE / self.p.baud

    def _may_send(self, tick: int, line: bytes) -> bool:
        """True if ``line`` written now would end after the interpreter's cycle of our previous line."""
        return tick * self.p.period_s + self._wire_s(line) >= self._cycle_free_s

    def _write(self, tick: int, line: bytes, out: SerialOut) -> None:
        out.tx += line
        end_s = tick * self.p.period_s + self._wire_s(line)
        self._cycle_free_s = end_s + 1.0 / self.p.cycle_hz + self.p.cycle_margin_s + self._extra_gap_s

    def _request(self, cmd: CommandSnapshot, st: StatusView):
        """(verb, line, requested ticks, target counts or None) for a command, or raise _Refused."""
        if cmd.cmd_mode == HOME_MODE:
            return kw.HOME, kw.format_home(cmd.cmd_id), 1, None
        if cmd.cmd_mode != NORMAL_MODE or not st.homed:
            raise _Refused()  # JOG, unknown modes; anything before homing
        gearing = self.model.gearing
        q_now = gearing.counts_to_joints(np.asarray(st.encoder_pos, float))
        if cmd.coord == CARTSPACE:
            if not np.all(np.isfinite(cmd.T)):
                raise _Refused()
            try:
                q = self.model.ik(cmd.T, q_now)
            except (Unreachable, ValueError):
                raise _Refused() from None
            pose = T_to_pose(self._base_inv @ cmd.T)
            want = max(cmd.cart_ticks, 0)
            return kw.MOVE, kw.format_move(cmd.cmd_id, pose, want * self.p.period_s), want, \
                gearing.joints_to_counts_int(q).astype(np.int32)
        if cmd.coord == JSPACE:
            counts = np.asarray(cmd.encoder_cmd_ext, np.int64)
            if np.any(counts < self.model.counts_min) or np.any(counts > self.model.counts_max):
                raise _Refused()
            q = gearing.counts_to_joints(counts.astype(float))
            if not self.model.within_limits(q):
                raise _Refused()
            want = max(cmd.joint_ticks, 0)
            return kw.JMOVE, kw.format_jmove(cmd.cmd_id, q, want * self.p.period_s), want, \
                counts.astype(np.int32)
        raise _Refused()

    # ------------------------------------------------------------------ busy
    def _busy(self, tick: int) -> None:
        f = self.flight
        if f is not None and not f.failed:
            if self.state == MOVING and f.ack_tick:
                left = f.ack_tick + f.planned_ticks - tick
            else:
                left = f.sent_tick + f.want_ticks - tick
            self.status["busy"] = max(1, left)
        elif self.pending is not None and self.pending.cmd_mode != OFF:
            self.status["busy"] = 1
        elif "busy" not in self.status and (f is None or f.failed):
            self.status["busy"] = 0

    @property
    def in_flight_id(self) -> int:
        return self.flight.cmd.cmd_id if self.flight is not None else 0


class _Refused(Exception):
    pass

