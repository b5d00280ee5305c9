"""droid-remote NAME...: the Brain-side remote client of a subunit (thesis §3.2, §4.1.8, §4.2.3).

Each heartbeat tick it copies the subunit's Command record from the Brain's
database into a message for the subunit's agent (located through the name
space), and writes the agent's reply into the Brain's Status record.  For an
arm it computes the wrist-centre pose by forward kinematics from the encoder
positions (§4.1.8: "it uses the forward kinematic model ... to calculate the
current cartesian position and orientation matrix of the wrist-center point").

A ``line_laser`` subunit with ``link = "serial"`` (the MVS sensor, the
tool-tip sensor) has no agent: the sensor writes its lines over a serial
cable straight to the Brain (§2.5, §5.4) and this program reads that port
instead (:mod:`droid.brain.runtime.sensor_link`).

Liveness (:class:`~droid.brain.plumbing.link.RemoteLinkCore`): ``stale_ticks`` ticks
without a reply set ``stale = 1`` in the Status record; the remote then
reconnects with back-off and clears ``stale`` on the next reply.

One process serves one subunit, as in the thesis, unless the cell says ``[brain] remotes =
"one"``: then ``droid-cell up`` starts one ``droid-remote`` naming every agent-linked subunit,
which serves them all from one loop on one heartbeat subscription (issue 28 item 4: each
remote process costs its wake-ups, 2-3 % of a core at 60 Hz, not its work).  Each subunit keeps
its own station, agent link, stale rule and Status; a subunit's link failing touches no other.
"""
from __future__ import annotations

import struct
import sys
import time

import numpy as np
import zmq

from droid.brain.plumbing import wire
from droid.brain.cell.cellfile import Subunit
from droid.brain.plumbing.curve import CurveHost
from droid.brain.db.databases import brain_layouts, open_brain
from droid.brain.runtime.heartbeat import TickSubscriber
from droid.brain.db.layouts import (ARM_COMMAND_LAYOUT, FAULT_HEARTBEAT, FAULT_LINK, LayoutError, byte_runs,
                                 check_header)
from droid.brain.plumbing.link import HeartbeatWatch, RemoteAction, RemoteLinkCore
from droid.brain.runtime.names import NameClient
from droid.brain.runtime.program import Presence, Stop, close_all, notify_ready, presence_key, subunit_program
from droid.brain.runtime.rt import try_sched_fifo
from droid.brain.runtime.sensor_link import LINK_SERIAL, link_kind, serve_serial
from droid.cli import BadInput, run

PROG = "droid-remote"


class ArmPose:
    """Forward kinematics of an arm subunit: encoder counts -> WCP pose in the global frame."""

    def __init__(self, sub: Subunit) -> None:
        from droid.kinematics import load_robot
        from droid.kinematics.transforms import pose_to_T

        self.model = load_robot(sub.robot).with_base(pose_to_T(*sub.base))

    def __call__(self, encoder_pos_counts) -> np.ndarray:
        q = self.model.gearing.counts_to_joints(np.asarray(encoder_pos_counts, float))
        return self.model.fk(q)


class StatusTranslator:
    """Agent reply (the subunit side's status record) -> Brain Status fields (the class's copy_fields).

    ``kind`` is the subunit's :class:`~droid.brain.cell.classes.SubunitClass`; ``fk`` (arms) maps
    encoder counts to the WCP pose, added to the fields once the arm is homed (§4.1.8); it must
    be a pure function of the counts: the last pose is reused while the counts stay the same."""

    def __init__(self, name: str, kind, fk=None) -> None:
        self.name = name
        self.reply_layout = kind.local["ctrl_status"]
        self.fields = kind.copy_fields
        self.fk = fk
        self._fk_last: tuple[bytes, np.ndarray] | None = None  # (encoder_pos bytes, its pose)

    @classmethod
    def for_subunit(cls, sub: Subunit) -> "StatusTranslator":
        return cls(sub.name, sub.kind, ArmPose(sub) if sub.kind.kinematic else None)

    def __call__(self, payload: bytes) -> dict:
        rec = self.record(payload)
        out = {f: rec[f] for f in self.fields}
        out.update(self.pose_fields(rec))
        return out

    def record(self, payload: bytes):
        """The reply's record (its header checked: LayoutError for a foreign one)."""
        check_header(payload, self.reply_layout, f"reply from {self.name}")
        return np.frombuffer(payload, dtype=self.reply_layout.dtype, count=1)[0]

    def byte_runs(self, layout) -> tuple | None:
        """The copied fields as byte ranges (reply offset, Status offset, bytes) into a record of
        ``layout`` (the Brain's Status), when each has the reply's type there -- copying those
        bytes then is the fields' assignment (droid.brain.db.layouts.byte_runs); else None."""
        if not all(f in layout.dtype.fields for f in self.fields):
            return None
        return byte_runs(self.reply_layout.dtype, layout.dtype, {f: f for f in self.fields})

    def pose_fields(self, rec) -> dict:
        """The WCP pose's fields (x, y, z, R) of the record once the arm is homed, else none."""
        T = self.pose_T(rec)
        return {} if T is None else {"x": T[0, 3], "y": T[1, 3], "z": T[2, 3], "R": T[:3, :3]}

    def pose_T(self, rec):
        """The WCP pose (4x4, mm) of the record once the arm is homed, else None."""
        if self.fk is None or not int(rec["homed"]):
            return None
        pos = rec["encoder_pos"]
        key, last = pos.tobytes(), self._fk_last
        if last is not None and last[0] == key:  # the same counts: the same pose (fk is a pure
            return last[1]  # function of them); an arm at rest (a holder) skips the FK
        T = self.fk(pos)
        self._fk_last = (key, T)
        return T


class RemoteStation:
    """droid-remote's cycle for an agent-linked subunit, transport aside (thesis §3.2, §4.1.8).

    Per heartbeat tick :meth:`on_tick` counts the missed reply (``stale`` and FAULT_LINK in
    the Brain's Status after ``stale_ticks``) and :meth:`command_payload` is the Command
    record to send; per reply :meth:`on_reply` writes the translated Status fields and, once
    the agent acknowledged the very command that was sent, clears ``sent`` (Table 3.2).
    ``status``/``command`` are the Brain's records (``command`` None for sensors).

    The heartbeat-silence rule is the station's too (issue 25 item 3; it lived in the real-time
    shell): :meth:`on_poll` with the time of every wake-up marks the Status stale with
    FAULT_LINK | FAULT_HEARTBEAT once no tick came for ``stale_ticks`` heartbeat periods, and the
    next tick (:meth:`on_tick` with its arrival time) clears FAULT_HEARTBEAT.  Real time passes
    the monotonic clock, lockstep its virtual time.
    """

    def __init__(self, status, command, translate: StatusTranslator, stale_ticks: int,
                 heartbeat_hz: float = 60.0) -> None:
        self.status = status
        self.command = command
        self.translate = translate
        self.core = RemoteLinkCore(stale_ticks)
        self.watch = HeartbeatWatch.for_rate(heartbeat_hz, stale_ticks)
        self.sent_cmd_id: int | None = None
        runs = getattr(translate, "byte_runs", None)
        self._runs = runs(status.layout) if runs is not None else None
        self._pack = (_reply_packers(status.layout.dtype) if self._runs is not None and hasattr(translate, "pose_T")
                      else None)  # the reply's tick and pose as two struct packs (issue 44)

    def on_poll(self, now_ns: int) -> bool:
        """A wake-up at ``now_ns`` (a tick or not): True once when the heartbeat fell silent."""
        if not self.watch.became_silent(now_ns):
            return False
        self.status.update(stale=1, fault=int(self.status.read()["fault"]) | FAULT_LINK | FAULT_HEARTBEAT)
        return True

    def on_tick(self, tick: int, now_ns: int | None = None) -> RemoteAction:
        """Heartbeat tick ``tick``, arrived at ``now_ns`` (None: no clock, the silence rule is
        not fed).  A tick after a silence clears FAULT_HEARTBEAT; the next reply clears stale."""
        if now_ns is not None and self.watch.on_tick(now_ns):
            self.status.update(fault=int(self.status.read()["fault"]) & ~FAULT_HEARTBEAT)
        act = self.core.on_tick(tick)
        if act.became_stale:
            self.status.update(stale=1, fault=int(self.status.read()["fault"]) | FAULT_LINK)
        return act

    def command_payload(self) -> bytes:
        payload = self.command.raw_bytes() if self.command is not None else b""
        self.sent_cmd_id = _cmd_id(payload, self.command.layout) if self.command is not None else None
        return payload

    def on_reply(self, tick: int, payload: bytes, now_ns: int) -> bool:
        """The agent's reply for ``tick``; True if it answered the pending command and was
        written.  Raises LayoutError for a record of a foreign layout."""
        if self._runs is not None:
            return self._reply_bytes(tick, payload, now_ns)
        fields = self.translate(payload)
        if not self.core.on_reply(tick):
            return False
        self.status.update(tick=tick, updated_ns=now_ns, stale=0, **fields)
        if self.command is not None:
            _ack_sent(self.command, self.sent_cmd_id)
        return True

    def _reply_bytes(self, tick: int, payload: bytes, now_ns: int) -> bool:
        """:meth:`on_reply` where the copied fields are byte ranges of both records (the 60 Hz
        reply of every arm, issue 44): the same record, one lock and one seq bump as ``update``."""
        translate = self.translate
        rec = translate.record(payload)
        pack = self._pack
        T = translate.pose_T(rec) if pack is not None else None
        pose = translate.pose_fields(rec) if pack is None else None
        if not self.core.on_reply(tick):
            return False
        with self.status.locked() as v:
            mv, src = memoryview(v).cast("B"), memoryview(payload)
            for s0, d0, n in self._runs:
                mv[d0:d0 + n] = src[s0:s0 + n]
            if pack is None:
                v["tick"], v["updated_ns"], v["stale"] = tick, now_ns, 0
                for k, val in pose.items():
                    v[k] = val
            else:
                (h_off, head), (p_off, packed_pose) = pack
                head.pack_into(mv, h_off, tick, now_ns, 0)  # v["tick"], v["updated_ns"], v["stale"]
                if T is not None:  # v["x"], v["y"], v["z"], v["R"]: the same doubles, row by row
                    (r0, r1, r2, _) = T.tolist()
                    packed_pose.pack_into(mv, p_off, r0[3], r1[3], r2[3], r0[0], r0[1], r0[2], r1[0], r1[1],
                                          r1[2], r2[0], r2[1], r2[2])
            self.status.mark_written()
        if self.command is not None:
            _ack_sent(self.command, self.sent_cmd_id)
        return True


def _reply_packers(dtype) -> tuple | None:
    """The reply's own writes into a Status record of ``dtype`` as two struct packs (issue 44):
    (offset, ``<QqI``) for tick, updated_ns and stale, (offset, ``<12d``) for x, y, z and R (row
    by row) -- where the record holds them so, side by side, in native little-endian order: then a
    pack writes the bytes numpy's field assignments write; else None (the assignments stay)."""
    f = dtype.fields
    want = (("tick", "<u8"), ("updated_ns", "<i8"), ("stale", "<u4"), ("x", "<f8"), ("y", "<f8"), ("z", "<f8"))
    if sys.byteorder != "little" or any(n not in f or f[n][0] != np.dtype(t) for n, t in want):
        return None
    if "R" not in f or f["R"][0] != np.dtype(("<f8", (3, 3))):
        return None
    t0, p0 = f["tick"][1], f["x"][1]
    if ((f["updated_ns"][1], f["stale"][1]) != (t0 + 8, t0 + 16)
            or (f["y"][1], f["z"][1], f["R"][1]) != (p0 + 8, p0 + 16, p0 + 24)):
        return None
    return (t0, struct.Struct("<QqI")), (p0, struct.Struct("<12d"))


@run
def main(argv=None) -> int:
    args, cell, subs = subunit_program(
        PROG, "Keep subunits' Brain databases in step with their agents, once per heartbeat.", argv,
        example="arm1 (several: one process serves them all)", several=True)
    serial = [s.name for s in subs if link_kind(cell, s) == LINK_SERIAL]
    if serial and len(subs) > 1:
        raise BadInput(f"{serial[0]} is serial-linked: its remote reads its port alone (name it by itself)")
    try_sched_fifo(wanted=cell.sched_fifo, prog=PROG)
    if link_kind(cell, subs[0]) == LINK_SERIAL:
        return serve_serial(cell, subs[0], args.ready_fd, PROG)
    ctx = zmq.Context()
    curve = CurveHost(ctx, cell, cell.brain_host)
    one = len(subs) == 1
    presence = Presence(cell.name, presence_key(PROG, subs[0].name if one else None),
                        f"{PROG} {subs[0].name}" if one else PROG)
    names = NameClient(ctx, cell.names, curve=curve, server_host=cell.brain_host)
    ticks = TickSubscriber(ctx, cell.heartbeat, curve, cell.brain_host)
    ticks.say = presence.say
    served: list[_Served] = []
    try:
        for sub in subs:
            served.append(_Served(ctx, cell, sub, names, curve))
        for s in served:
            s.status.update(stale=1, fault=FAULT_LINK)
            s.link.connect()
        presence.ready()
        notify_ready(args.ready_fd)
        _serve(served, ticks, presence)
    finally:
        close_all(names, ticks, *served, curve, ctx.term, presence)
    return 0


class _Served:
    """One subunit a droid-remote serves: its Brain records, its station and its agent link."""

    def __init__(self, ctx, cell, sub, names: NameClient, curve: CurveHost) -> None:
        self.status = open_brain(cell, sub, "status")
        self.command = open_brain(cell, sub, "command") if "command" in brain_layouts(sub) else None
        self.station = RemoteStation(self.status, self.command, StatusTranslator.for_subunit(sub),
                                     cell.stale_ticks, cell.heartbeat_hz)
        self.link = _AgentLink(ctx, names, curve, sub)

    def close(self) -> None:
        close_all(self.link, self.status, self.command)


class _AgentLink:
    """The DEALER socket to the subunit's agent, at the endpoint the name service gives (located
    again whenever the link core asks for a reconnect or there is none)."""

    def __init__(self, ctx, names: NameClient, curve: CurveHost, sub) -> None:
        self.ctx, self.names, self.curve, self.sub = ctx, names, curve, sub
        self.dealer = None
        self.endpoint = None
        self.bad_frames = 0  # replies that were not a Status record of ours

    def connect(self) -> None:
        if self.dealer is not None:
            self.dealer.close(0)
            self.dealer = None
        self.endpoint = self.names.locate(self.sub.name, timeout_s=0.05)
        if self.endpoint:
            dealer = self.dealer = self.ctx.socket(zmq.DEALER)
            dealer.setsockopt(zmq.LINGER, 0)
            dealer.setsockopt(zmq.SNDHWM, 2)
            dealer.setsockopt(zmq.RCVHWM, 8)
            self.curve.client(dealer, self.endpoint, self.sub.host)
            dealer.connect(self.endpoint)

    def send(self, tick: int, payload: bytes) -> None:
        """The Command record for heartbeat ``tick`` (dropped when the agent is not keeping up)."""
        try:
            self.dealer.send_multipart(wire.pack_link(wire.KIND_CMD, tick, payload), zmq.NOBLOCK)
        except zmq.Again:
            pass

    def drain(self, station: RemoteStation) -> None:
        """Every reply that arrived, into the station; bad frames counted."""
        while True:
            try:
                frames = self.dealer.recv_multipart(zmq.NOBLOCK)
            except zmq.Again:
                break
            try:
                tick, payload = wire.unpack_link(frames, wire.KIND_STA)
                station.on_reply(tick, payload, time.monotonic_ns())
            except (wire.BadFrame, LayoutError):
                self.bad_frames += 1
                continue

    def close(self) -> None:
        if self.dealer is not None:
            self.dealer.close(0)


def _serve(served: list[_Served], ticks: TickSubscriber, presence: Presence) -> None:
    """droid-remote's loop, until SIGTERM: on each heartbeat tick send each subunit's Command to
    its agent; every reply into its Status record; the silence rule on every wake-up."""
    last_tick = 0
    poll_ms = min(s.station.watch.poll_ms for s in served)
    while not Stop.requested:
        poller = zmq.Poller()
        poller.register(ticks.sock, zmq.POLLIN)
        for s in served:
            if s.link.dealer is not None:
                poller.register(s.link.dealer, zmq.POLLIN)
        events = dict(poller.poll(poll_ms))
        now = time.monotonic_ns()
        for s in served:
            s.station.on_poll(now)
        if ticks.sock in events:
            t = ticks.recv_latest()
            if t is not None:
                last_tick = t.tick
                now = time.monotonic_ns()
                for s in served:
                    act = s.station.on_tick(t.tick, now)
                    if act.reconnect or s.link.dealer is None:
                        s.link.connect()
                    if s.link.dealer is not None:
                        s.link.send(t.tick, s.station.command_payload())
        for s in served:
            if s.link.dealer is not None and s.link.dealer in events:
                s.link.drain(s.station)
        if presence.due():
            presence.beat(last_tick, sum(s.station.core.replies for s in served), ticks.monitor.missed,
                          ticks.lateness_max_ns, bad_frames=sum(s.link.bad_frames for s in served) + ticks.bad_frames)


def _cmd_id(payload: bytes, layout=ARM_COMMAND_LAYOUT) -> int | None:
    """The ``cmd_id`` of a Command record's bytes (every commandable class's layout has one)."""
    if len(payload) < layout.size:
        return None
    return int(np.frombuffer(payload, dtype=layout.dtype, count=1)[0]["cmd_id"])


def _ack_sent(command, delivered_cmd_id: int | None) -> None:
    """Clear Command.sent once the agent acknowledged that very command (Table 3.2 'sent')."""
    if delivered_cmd_id is None:
        return
    with command.locked() as rec:
        if int(rec["sent"]) and int(rec["cmd_id"]) == delivered_cmd_id:
            rec["sent"] = 0
            command.mark_written()


if __name__ == "__main__":
    sys.exit(main())
