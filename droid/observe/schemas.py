"""JSON Schemas of DROID records and Foxglove's well-known schemas (docs/observe.md).

A recording's channels carry JSON messages with a JSON Schema (MCAP encoding
``json``, schema encoding ``jsonschema``), so any MCAP reader (Foxglove,
Lichtblick, ``mcap cat --json``) needs nothing but the file.  The schema of a
database record is derived from its layout's numpy dtype
(:mod:`droid.brain.db.layouts`), so it follows any layout without a field list
kept by hand; the record <-> JSON conversion is generic the same way.
"""
from __future__ import annotations

import json

import numpy as np

from droid.brain.db.layouts import HEADER_FIELDS, Layout

HEADER_NAMES = tuple(name for name, _, _ in HEADER_FIELDS)
#: header fields a writer owns: not written back by a replay (seq, writer and holder pid)
HEADER_KEEP = ("magic", "version", "kind", "size", "writer_pid", "holder_pid", "flags", "seq")


def _json_type(base: np.dtype) -> dict:
    if base.kind in "iu":
        return {"type": "integer"}
    if base.kind == "f":
        return {"type": "number"}
    if base.kind in "SU":
        return {"type": "string", "maxLength": base.itemsize}
    raise ValueError(f"no JSON type for dtype {base}")


def _array_schema(item: dict, shape: tuple) -> dict:
    s = item
    for n in reversed(shape):
        s = {"type": "array", "items": s, "minItems": n, "maxItems": n}
    return s


def record_schema(layout: Layout) -> dict:
    """JSON Schema of one ``layout`` record as :func:`record_to_dict` writes it, plus ``tick``
    (the heartbeat tick the sample was taken at) and ``subunit``."""
    props: dict = {"_tick": {"type": "integer", "description": "heartbeat tick of the sample"},
                   "_subunit": {"type": "string"}}
    for name in layout.dtype.names:
        base, shape = layout.dtype.fields[name][0].base, layout.dtype.fields[name][0].shape
        props[name] = _array_schema(_json_type(base), shape) if shape else _json_type(base)
    # the path every recording has carried since the layouts were defined: kept, so that the
    # split of droid.brain (issue 43 item 5; the module is droid/brain/db/layouts.py now) leaves
    # recordings byte-identical
    return {"title": f"droid.{layout.name}", "type": "object",
            "description": f"DROID {layout.name} record, layout version {layout.version} "
                           f"(droid/brain/layouts.py; C struct {layout.c_name})",
            "properties": props, "required": list(layout.dtype.names)}


def record_to_dict(rec: np.ndarray) -> dict:
    """A 0-d structured record as a JSON-ready dict (every field, header included; floats exact)."""
    vals = rec.tolist()
    out = {}
    for name, v in zip(rec.dtype.names, vals):
        if isinstance(v, np.ndarray):
            v = v.tolist()
        if isinstance(v, bytes):
            v = v.decode(errors="replace").rstrip("\x00")
        elif isinstance(v, (list, tuple)) and v and isinstance(v[0], bytes):  # names (guard_status.arms)
            v = [b.decode(errors="replace").rstrip("\x00") for b in v]
        out[name] = v
    return out


def dict_to_record(d: dict, layout: Layout, rec: np.ndarray) -> None:
    """Write the payload fields of ``d`` into ``rec`` (a record of ``layout``), header kept."""
    for name in layout.dtype.names:
        if name in HEADER_KEEP or name not in d:
            continue
        v = d[name]
        if isinstance(v, list) and v and isinstance(v[0], str):
            v = [x.encode() for x in v]
        rec[name] = v.encode() if isinstance(v, str) else v


# -- Foxglove well-known schemas (https://docs.foxglove.dev/docs/visualization/message-schemas) --
_TIME = {"type": "object", "properties": {"sec": {"type": "integer", "minimum": 0},
                                          "nsec": {"type": "integer", "minimum": 0}}}
_VEC3 = {"type": "object", "properties": {k: {"type": "number"} for k in "xyz"}}
_QUAT = {"type": "object", "properties": {k: {"type": "number"} for k in "xyzw"}}
_POSE = {"type": "object", "properties": {"position": _VEC3, "orientation": _QUAT}}
_COLOR = {"type": "object", "properties": {k: {"type": "number"} for k in ("r", "g", "b", "a")}}
_FRAME_TRANSFORM = {
    "type": "object", "title": "foxglove.FrameTransform",
    "properties": {"timestamp": _TIME, "parent_frame_id": {"type": "string"},
                   "child_frame_id": {"type": "string"}, "translation": _VEC3, "rotation": _QUAT},
}
FRAME_TRANSFORMS = {"title": "foxglove.FrameTransforms", "type": "object",
                    "properties": {"transforms": {"type": "array", "items": _FRAME_TRANSFORM}}}
LOG = {
    "title": "foxglove.Log", "type": "object",
    "properties": {"timestamp": _TIME,
                   "level": {"type": "integer", "description": "0 UNKNOWN 1 DEBUG 2 INFO 3 WARNING 4 ERROR 5 FATAL"},
                   "message": {"type": "string"}, "name": {"type": "string"},
                   "file": {"type": "string"}, "line": {"type": "integer", "minimum": 0}},
}
SCENE_UPDATE = {
    "title": "foxglove.SceneUpdate", "type": "object",
    "properties": {
        "deletions": {"type": "array", "items": {"type": "object"}},
        "entities": {"type": "array", "items": {
            "type": "object",
            "properties": {
                "timestamp": _TIME, "frame_id": {"type": "string"}, "id": {"type": "string"},
                "lifetime": _TIME, "frame_locked": {"type": "boolean"},
                "cubes": {"type": "array", "items": {"type": "object", "properties": {
                    "pose": _POSE, "size": _VEC3, "color": _COLOR}}},
                "lines": {"type": "array", "items": {"type": "object", "properties": {
                    "type": {"type": "integer", "description": "0 LINE_STRIP 1 LINE_LOOP 2 LINE_LIST"},
                    "pose": _POSE, "thickness": {"type": "number"},
                    "scale_invariant": {"type": "boolean"},
                    "points": {"type": "array", "items": _VEC3}, "color": _COLOR,
                    "colors": {"type": "array", "items": _COLOR},
                    "indices": {"type": "array", "items": {"type": "integer"}}}}},
            }}},
    },
}
HEALTH = {
    "title": "droid.health", "type": "object",
    "description": "program health: droid-cell status --json rows, plus the heartbeat's lateness",
    "properties": {"_tick": {"type": "integer"},
                   "programs": {"type": "array", "items": {"type": "object"}},
                   "heartbeat": {"type": "object", "properties": {
                       "lateness_max_ns": {"type": "integer"}, "overruns": {"type": "integer"},
                       "last_tick": {"type": "integer"}}}},
}
TICK = {
    "title": "droid.tick", "type": "object",
    "description": "one heartbeat tick of the recording: tick number, CLOCK_MONOTONIC [ns], ticks missed",
    "properties": {"_tick": {"type": "integer"}, "t_ns": {"type": "integer"}, "missed": {"type": "integer"}},
}

_NUM_OR_NULL = {"type": ["number", "null"]}
GUARD_VIEW = {
    "title": "droid.guard_view", "type": "object",
    "description": "the collision guard as the viewers show it (docs/guard.md §7a): state off|clear|slowing|stopped "
                   "(off: no [guard] table, run = false, or no pass yet; why says which), the least distance [mm], "
                   "the closest pair and its two closest points [mm, world], the override per arm, closing speed "
                   "[mm/s] and S_p [mm] of the deciding pair",
    "properties": {"state": {"type": "string"}, "why": {"type": ["string", "null"]},
                   "tick": {"type": ["integer", "null"]}, "distance_mm": _NUM_OR_NULL,
                   "pair": {"type": ["array", "null"], "items": {"type": "object", "properties": {
                       "arm": {"type": "string"}, "body": {"type": "string"}}}},
                   "points": {"type": ["array", "null"], "items": {"type": "array", "items": {"type": "number"}}},
                   "override": {"type": "object", "additionalProperties": _NUM_OR_NULL},
                   "closing_mm_s": _NUM_OR_NULL, "separation_mm": _NUM_OR_NULL,
                   "trips": {"type": ["integer", "null"]}, "stale": {"type": "boolean"}},
}


def schema_bytes(schema: dict) -> bytes:
    return json.dumps(schema, separators=(",", ":")).encode()
