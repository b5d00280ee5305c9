"""The MCAP layout of a DROID recording (docs/observe.md), its writer and its checked reader.

One file per recording, written with the ``mcap`` package (MCAP is ROS 2's
default bag format, read by Foxglove, Lichtblick and the ``mcap`` CLI):

* header profile ``droid``; right after it a metadata record ``droid`` (every value
  JSON-encoded) holding
  ``format_version``, the cell (name, heartbeat rate, subunits with their
  class, robot, base and database layouts with versions), the wrist/workpiece
  geometry the scene needs and the source (``live`` or ``lockstep``), so a
  reader needs nothing but the file;
* every message's ``sequence`` is the heartbeat tick it belongs to and its
  ``log_time`` the tick's time [ns]; every JSON message also carries ``_tick``;
* channels (JSON messages, JSON Schema): ``/tick`` (droid.tick), one per
  database ``/<subunit>/<area>`` (droid.<layout>, e.g. ``/arm1/status``,
  ``/arm1/command``, ``/mvs/status``), ``/health`` (droid.health: the
  ``droid-cell status --json`` rows), ``/log`` (foxglove.Log: faults and
  events), ``/tf`` (foxglove.FrameTransforms) and ``/scene``
  (foxglove.SceneUpdate);
* chunked, and every chunk is closed at least once a second of ticks
  (``flush_ticks``), so an unclean stop loses at most the open chunk; the
  reader reads the data section in order, so a file without its footer
  (truncated) is reported, and :func:`recover` rewrites what survives.
"""
from __future__ import annotations

import json
import os
import struct
from dataclasses import dataclass, field

from mcap.records import Channel, Chunk, Footer, Header, Message, Metadata, Schema
from mcap.stream_reader import StreamReader, breakup_chunk
from mcap.writer import CompressionType, Writer

from droid.brain.db.layouts import Layout
from droid.cli import BadInput, open_input
from droid.observe import schemas

PROFILE = "droid"
META_NAME = "droid"
FORMAT_VERSION = 1
MCAP_MAGIC = b"\x89MCAP0\r\n"
CHUNK_BYTES = 256 * 1024  # a chunk closes at this size of uncompressed messages ...
FLUSH_TICKS = 60  # ... or after this many heartbeat ticks (1 s at 60 Hz), whichever comes first
TOPIC_TICK, TOPIC_HEALTH, TOPIC_LOG, TOPIC_TF, TOPIC_SCENE = "/tick", "/health", "/log", "/tf", "/scene"
# foxglove.Log levels
LOG_INFO, LOG_WARNING, LOG_ERROR = 2, 3, 4


def db_topic(subunit: str, area: str) -> str:
    """Channel topic of one database: ``/<subunit>/<area>``."""
    return f"/{subunit}/{area}"


class BadRecording(BadInput):
    """A file that is not a DROID recording this program can read (exit 2)."""


class RecordingWriter:
    """Writes one DROID recording.  ``meta``: the ``droid`` metadata (see :func:`cell_meta`)."""

    def __init__(self, path: str | os.PathLike, meta: dict, *, flush_ticks: int = FLUSH_TICKS,
                 compression: CompressionType = CompressionType.ZSTD) -> None:
        self.path = str(path)
        try:
            self._f = open(self.path, "wb")
        except OSError as exc:
            raise BadInput(f"cannot write {self.path}: {exc.strerror}") from None
        self._w = Writer(self._f, chunk_size=CHUNK_BYTES, compression=compression)
        self._w.start(profile=PROFILE, library=f"droid-record (format {FORMAT_VERSION})")
        self.meta = dict(meta, format_version=FORMAT_VERSION)
        # every value JSON-encoded (strings too), so a reader gets back exactly what was written
        self._w.add_metadata(META_NAME, {k: json.dumps(v) for k, v in self.meta.items()})
        self._schemas: dict[str, int] = {}
        self._channels: dict[str, int] = {}
        self._record_schemas: dict[str, dict] = {}
        self._enc = json.JSONEncoder(separators=(",", ":"), allow_nan=True)
        self.flush_ticks = flush_ticks
        self._ticks_in_chunk = 0
        self.messages = 0
        self.closed = False

    def _channel(self, topic: str, schema: dict, metadata: dict | None = None) -> int:
        cid = self._channels.get(topic)
        if cid is None:
            name = schema["title"]
            sid = self._schemas.get(name)
            if sid is None:
                sid = self._w.register_schema(name, "jsonschema", schemas.schema_bytes(schema))
                self._schemas[name] = sid
            cid = self._w.register_channel(topic, "json", sid, metadata or {})
            self._channels[topic] = cid
        return cid

    def write(self, topic: str, schema: dict, obj: dict, tick: int, t_ns: int, metadata: dict | None = None) -> None:
        """One JSON message on ``topic`` for heartbeat ``tick`` at time ``t_ns`` [ns]."""
        cid = self._channel(topic, schema, metadata)
        obj["_tick"] = int(tick)
        data = self._enc.encode(obj).encode()
        self._w.add_message(cid, log_time=int(t_ns), data=data, publish_time=int(t_ns), sequence=int(tick) & 0xFFFFFFFF)
        self.messages += 1

    def tick(self, tick: int, t_ns: int, missed: int = 0) -> None:
        """Start heartbeat ``tick``: a ``/tick`` message; closes the chunk every ``flush_ticks``."""
        self._ticks_in_chunk += 1
        if self._ticks_in_chunk > self.flush_ticks:
            self.flush()
        self.write(TOPIC_TICK, schemas.TICK, {"t_ns": int(t_ns), "missed": int(missed)}, tick, t_ns)

    def record(self, subunit: str, area: str, layout: Layout, rec, tick: int, t_ns: int) -> dict:
        """One database record (a 0-d structured array of ``layout``, or its dict); returns the dict."""
        d = rec if isinstance(rec, dict) else schemas.record_to_dict(rec)
        d["_subunit"] = subunit
        sch = self._record_schemas.get(layout.name)
        if sch is None:
            sch = self._record_schemas[layout.name] = schemas.record_schema(layout)
        self.write(db_topic(subunit, area), sch, d, tick, t_ns,
                   {"layout": layout.name, "version": str(layout.version), "subunit": subunit, "area": area})
        return d

    def log(self, tick: int, t_ns: int, level: int, message: str, name: str) -> None:
        """A fault or event as a foxglove.Log message."""
        self.write(TOPIC_LOG, schemas.LOG, {"timestamp": stamp(t_ns), "level": level, "message": message,
                                            "name": name, "file": "", "line": 0}, tick, t_ns)

    def flush(self) -> None:
        """Close the open chunk and write it out (an unclean stop after this loses nothing before)."""
        self._w.flush()
        self._ticks_in_chunk = 0

    def close(self) -> None:
        if self.closed:
            return
        self.closed = True
        self._w.finish()
        self._f.close()

    def __enter__(self) -> "RecordingWriter":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def stamp(t_ns: int) -> dict:
    """A foxglove Time {sec, nsec} of ``t_ns`` [ns]."""
    t = max(0, int(t_ns))
    return {"sec": t // 1_000_000_000, "nsec": t % 1_000_000_000}


def cell_meta(cell, source: str, scene: dict | None = None) -> dict:
    """The ``droid`` metadata of a recording of ``cell`` (layouts read from the cell generically)."""
    from droid.brain.db.databases import brain_layouts

    subs = []
    for sub in cell.subunits.values():
        subs.append({"name": sub.name, "class": sub.cls, "robot": sub.robot, "base": list(sub.base),
                     "areas": {area: {"layout": lay.name, "version": lay.version}
                               for area, lay in brain_layouts(sub).items()}})
    return {"cell": cell.name, "heartbeat_hz": cell.heartbeat_hz, "source": source,
            "subunits": subs, "scene": scene or {}, "guard": guard_meta(cell)}


def guard_meta(cell) -> dict:
    """Whether the cell declares a collision guard (``[guard]``) and runs it live (``run``, true by
    default; docs/guard.md §9): what a viewer says when no droid-guard writes its Status."""
    table = cell.raw.get("guard")
    if table is None:
        return {"declared": False, "run": False}
    run = table.get("run", True) if isinstance(table, dict) else True
    return {"declared": True, "run": run is True}


# ---------------------------------------------------------------- reading
@dataclass
class Recording:
    """A DROID recording read into memory: metadata, channels and every message by tick."""

    path: str
    meta: dict
    channels: dict[str, dict] = field(default_factory=dict)  # topic -> channel metadata + schema name
    ticks: list[int] = field(default_factory=list)  # tick numbers in order
    frames: list[dict] = field(default_factory=list)  # per tick: {topic: [message dicts]}
    t_ns: list[int] = field(default_factory=list)  # per tick: its time [ns]
    complete: bool = True  # False: the footer is missing (recovered up to the last whole chunk)

    @property
    def subunits(self) -> list[dict]:
        return self.meta.get("subunits", [])

    def layouts(self) -> dict[tuple[str, str], tuple[str, int]]:
        """(subunit, area) -> (layout name, version) of every database channel."""
        out = {}
        for ch in self.channels.values():
            if "layout" in ch:
                out[(ch["subunit"], ch["area"])] = (ch["layout"], int(ch["version"]))
        return out

    def index_of(self, tick: int) -> int:
        """Index of the last recorded tick <= ``tick`` (0 if before the first)."""
        import bisect

        return max(0, bisect.bisect_right(self.ticks, tick) - 1)


def read_recording(path: str | os.PathLike, *, allow_truncated: bool = False) -> Recording:
    """Read and check a DROID recording; :class:`BadRecording` (exit 2) with a one-line reason for a
    missing, foreign, future-version or truncated file (``allow_truncated``: keep what survives)."""
    p = str(path)
    with open_input(p, "", BadRecording, missing="no such file") as f:
        if f.read(len(MCAP_MAGIC)) != MCAP_MAGIC:
            raise BadRecording(f"{p}: not an MCAP file")
        f.seek(0)
        return _read(p, f, allow_truncated)


def _messages(p: str, f, allow_truncated: bool, st: dict, topics=None):
    """The checked messages of an open recording, in file order: ``(topic, tick, log_time [ns], obj)``.

    ``st`` gets ``rec`` (the :class:`Recording` with its metadata, once read), ``chans``, ``schemas`` and
    ``saw_footer``; ``topics``: decode only these topics (None: all).  :class:`BadRecording` (one line)
    for a foreign, future-version, damaged or (unless ``allow_truncated``) truncated file."""
    st["rec"], st["chans"], st["schemas"], st["saw_footer"] = None, {}, {}, False
    chans: dict[int, Channel] = st["chans"]
    fast = topics is not None  # read chunks of messages ourselves, decoding only the wanted ones
    reader = StreamReader(f, record_size_limit=256 * 2**20, emit_chunks=fast)

    def records():
        wanted, known = set(), -1
        for r in reader.records:
            if isinstance(r, Chunk):
                if len(chans) != known:  # channel ids of the wanted topics (unknown ids are kept, and refused)
                    wanted = {cid for cid, ch in chans.items() if ch.topic in topics}
                    known = len(chans)
                msgs = _chunk_messages(r, wanted, chans)
                yield from (breakup_chunk(r) if msgs is None else msgs)
            else:
                yield r

    try:
        for r in records():
            if isinstance(r, (Message, tuple)):
                cid, seq, log_time, data = ((r.channel_id, r.sequence, r.log_time, r.data)
                                            if isinstance(r, Message) else r)
                if st["rec"] is None:
                    raise BadRecording(f"{p}: messages before the droid metadata (not a DROID recording)")
                ch = chans.get(cid)
                if ch is None:
                    raise BadRecording(f"{p}: message on unknown channel {cid}")
                if topics is not None and ch.topic not in topics:
                    continue
                try:
                    obj = json.loads(data)
                except ValueError:
                    raise BadRecording(f"{p}: message on {ch.topic} is not JSON") from None
                tick = int(obj.get("_tick", seq)) if isinstance(obj, dict) else seq
                yield ch.topic, tick, log_time, obj
            elif isinstance(r, Header):
                if r.profile != PROFILE:
                    raise BadRecording(f"{p}: foreign MCAP file (profile {r.profile!r}, library "
                                       f"{r.library!r}), not a DROID recording")
            elif isinstance(r, Metadata) and r.name == META_NAME and st["rec"] is None:
                meta = {}
                for k, v in r.metadata.items():
                    try:
                        meta[k] = json.loads(v)
                    except ValueError:
                        meta[k] = v
                ver = meta.get("format_version")
                if not isinstance(ver, int):
                    raise BadRecording(f"{p}: DROID recording without a format version")
                if ver > FORMAT_VERSION:
                    raise BadRecording(f"{p}: recording format version {ver} is newer than this droid "
                                       f"reads (up to {FORMAT_VERSION})")
                st["rec"] = Recording(p, meta)
            elif isinstance(r, Schema):
                st["schemas"][r.id] = r
            elif isinstance(r, Channel):
                chans[r.id] = r
            elif isinstance(r, Footer):
                st["saw_footer"] = True
    except BadRecording:
        raise
    except Exception as exc:  # noqa: BLE001 -- any decode failure of a damaged file (McapError, EOF, struct...)
        if st["rec"] is not None and allow_truncated:
            pass
        else:
            what = "truncated" if st["rec"] is not None else "unreadable"
            raise BadRecording(f"{p}: {what} MCAP ({type(exc).__name__}: {str(exc)[:80] or 'no footer'}); "
                               f"'droid-replay {p} --recover OUT.mcap' keeps its whole chunks") from None
    if st["rec"] is None:
        raise BadRecording(f"{p}: no droid metadata (not a DROID recording)")
    if not st["saw_footer"] and not allow_truncated:
        raise BadRecording(f"{p}: truncated MCAP (no footer: the recording stopped uncleanly); "
                           f"'droid-replay {p} --recover OUT.mcap' keeps its whole chunks")


_MESSAGE_OP = 0x05  # MCAP opcode of a Message record


def _chunk_messages(chunk: Chunk, wanted: set[int], known: dict) -> list[tuple] | None:
    """The Message records of a chunk on the ``wanted`` channel ids (and on ids not ``known``, which
    the caller refuses) as ``(channel_id, sequence, log_time, data)``, parsed straight from its bytes
    (the ``mcap`` record classes cost several times more); None when the chunk holds any other
    record (a schema or channel: the caller lets ``mcap`` parse it)."""
    if chunk.compression == "zstd":
        import zstandard

        data = zstandard.decompress(chunk.data, chunk.uncompressed_size)
    elif chunk.compression == "":
        data = chunk.data
    else:
        return None
    out = []
    pos, n = 0, len(data)
    unpack = struct.unpack_from
    while pos < n:
        if data[pos] != _MESSAGE_OP:
            return None
        (length,) = unpack("<Q", data, pos + 1)
        body = pos + 9
        cid, seq, log_time = unpack("<HIQ", data, body)
        if cid in wanted or cid not in known:
            out.append((cid, seq, log_time, data[body + 22:body + length]))  # 22: id u16, seq u32, log/publish u64
        pos = body + length
    if pos != n:
        raise ValueError("chunk records overrun the chunk")
    return out


def _read(p: str, f, allow_truncated: bool) -> Recording:
    frames_by_tick: dict[int, dict] = {}
    t_by_tick: dict[int, int] = {}
    st: dict = {}
    for topic, tick, log_time, obj in _messages(p, f, allow_truncated, st):
        frames_by_tick.setdefault(tick, {}).setdefault(topic, []).append(obj)
        t_by_tick.setdefault(tick, log_time)
    rec = st["rec"]
    rec.complete = st["saw_footer"]
    for ch in st["chans"].values():
        sc = st["schemas"].get(ch.schema_id)
        rec.channels[ch.topic] = dict(ch.metadata, schema=sc.name if sc else "")
    rec.ticks = sorted(frames_by_tick)
    rec.frames = [frames_by_tick[t] for t in rec.ticks]
    rec.t_ns = [t_by_tick[t] for t in rec.ticks]
    return rec


def read_meta(path: str | os.PathLike) -> dict:
    """The ``droid`` metadata of a recording, read from the head of the file only (checked like
    :func:`read_recording`: not MCAP, foreign or a newer format version: :class:`BadRecording`)."""
    p = str(path)
    with open_input(p, "", BadRecording, missing="no such file") as f:
        if f.read(len(MCAP_MAGIC)) != MCAP_MAGIC:
            raise BadRecording(f"{p}: not an MCAP file")
        f.seek(0)
        st: dict = {}
        gen = _messages(p, f, True, st)
        try:
            for _ in gen:  # the metadata comes right after the header, before any message
                break
        finally:
            gen.close()
        if st.get("rec") is None:
            raise BadRecording(f"{p}: no droid metadata (not a DROID recording)")
        return st["rec"].meta


def stream_ticks(path: str | os.PathLike, topics=None, on_meta=None):
    """A complete recording read tick by tick, without holding it in memory (exports of long files):
    yields ``(tick, t_ns, {topic: [message dicts]})`` in file order, decoding only ``topics`` (None: all);
    ``on_meta(meta)`` is called once with the ``droid`` metadata before the first tick.  The file is
    checked as :func:`read_recording` checks it; a file without the closing magic (truncated) is
    refused before anything is yielded."""
    p = str(path)
    with open_input(p, "", BadRecording, missing="no such file") as f:
        if f.read(len(MCAP_MAGIC)) != MCAP_MAGIC:
            raise BadRecording(f"{p}: not an MCAP file")
        f.seek(0, os.SEEK_END)
        if f.tell() < 2 * len(MCAP_MAGIC) or (f.seek(-len(MCAP_MAGIC), os.SEEK_END), f.read())[1] != MCAP_MAGIC:
            raise BadRecording(f"{p}: truncated MCAP (no footer: the recording stopped uncleanly); "
                               f"'droid-replay {p} --recover OUT.mcap' keeps its whole chunks")
        f.seek(0)
        st: dict = {}
        cur, t_cur, frame = None, 0, {}
        for topic, tick, log_time, obj in _messages(p, f, False, st, topics):
            if tick != cur:
                if cur is not None:
                    yield cur, t_cur, frame
                elif on_meta is not None:
                    on_meta(st["rec"].meta)
                cur, t_cur, frame = tick, log_time, {}
            frame.setdefault(topic, []).append(obj)
        if cur is None and on_meta is not None:
            on_meta(st["rec"].meta)
        if cur is not None:
            yield cur, t_cur, frame


def recover(src: str, dst: str) -> Recording:
    """Rewrite the whole chunks of a truncated recording ``src`` into a complete file ``dst``."""
    rec = read_recording(src, allow_truncated=True)
    write_recording(rec, dst)
    return rec


def write_recording(rec: Recording, dst: str, ticks: range | None = None) -> None:
    """Write ``rec`` (or the frames of ``ticks`` indices) as a complete recording ``dst``."""
    from droid.brain.db.layouts import LAYOUTS

    by_name = {lay.name: lay for lay in LAYOUTS.values()}
    schema_of = {TOPIC_TICK: schemas.TICK, TOPIC_HEALTH: schemas.HEALTH, TOPIC_LOG: schemas.LOG,
                 TOPIC_TF: schemas.FRAME_TRANSFORMS, TOPIC_SCENE: schemas.SCENE_UPDATE}
    meta = {k: v for k, v in rec.meta.items() if k != "format_version"}
    with RecordingWriter(dst, meta) as w:
        for i in (ticks if ticks is not None else range(len(rec.ticks))):
            tick, t_ns = rec.ticks[i], rec.t_ns[i]
            for topic, msgs in rec.frames[i].items():
                ch = rec.channels.get(topic, {})
                if "layout" in ch and ch["layout"] in by_name:
                    sch, md = schemas.record_schema(by_name[ch["layout"]]), {k: v for k, v in ch.items() if k != "schema"}
                else:
                    sch, md = schema_of.get(topic, {"title": ch.get("schema") or "droid.unknown"}), None
                for m in msgs:
                    w.write(topic, sch, dict(m), tick, t_ns, md)
