"""droid-web and droid-foxglove show the collision guard (issue 41 item 5; docs/guard.md §7a):
the least distance, the closest pair and the line between its two closest points, the state and
the override per arm -- from a recording with ``/guard/status`` (tests/observe/webutil.py's
guard_recording: droid-guard's station over two arms' Status records as both stretch toward each
other) -- and ``off``, with why, where the cell has no guard, ``run = false`` or no pass yet."""
from __future__ import annotations

import math

import numpy as np
import pytest

from tests.observe.webutil import WebServer, guard_cell, guard_recording, lockstep_recording


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    return guard_recording(tmp_path_factory.mktemp("guardview") / "guard.mcap")


def _joints(rec, i):
    from droid.kinematics import load_robot

    cell = guard_cell()
    fr = rec.frames[i]
    return {n: load_robot(cell.subunits[n].robot).gearing.counts_to_joints(
        np.asarray(fr[f"/{n}/status"][-1]["encoder_pos"], float)) for n in ("arm1", "arm2")}


def test_the_guard_status_carries_the_closest_pairs_points(recording):
    """The recorded closest points are those of the guard's numpy reference at the recorded joints,
    on the recorded pair's bodies (independent of the pass that wrote them)."""
    from droid.guard.cell import guard_scene
    from droid.observe.mcapfile import read_recording

    rec = read_recording(recording)
    scene = guard_scene(guard_cell())
    keys = [(a.key, b.key) for a, b in scene.pairs]
    seen = 0
    for i in range(0, len(rec.ticks), 5):
        g = rec.frames[i]["/guard/status"][-1]
        q = _joints(rec, i)
        d, pa, pb = scene.closest_points_reference({n: v[None] for n, v in q.items()})
        k = keys.index((f"{g['a_arm']}.{g['a_body']}", f"{g['b_arm']}.{g['b_body']}"))
        assert g["distance_mm"] == pytest.approx(float(d[0].min()), abs=1e-6)
        assert float(d[0, k]) == pytest.approx(g["distance_mm"], abs=1e-6)
        assert np.allclose(g["a_point_mm"], pa[0, k], atol=1e-6) and np.allclose(g["b_point_mm"], pb[0, k], atol=1e-6)
        seen += 1
    assert seen > 10


def test_droid_web_shows_the_guard_of_a_recording(recording):
    """The snapshots of a recording (droid-web --file) carry the guard: clear, then slowing, then
    stopped as the arms close; the pair's two points, its distance and the override per arm."""
    from droid.observe.mcapfile import read_recording
    from droid.observe.sources import FileSource

    src = FileSource(recording)
    rec = read_recording(recording)
    states = [s["guard"]["state"] for s in src.snaps]
    assert states[0] == "clear" and "slowing" in states and states[-1] == "stopped"
    assert states.index("slowing") < states.index("stopped")
    assert "guard" not in src.snaps[0]["subunits"]  # the guard is not drawn as a subunit row
    for i, s in enumerate(src.snaps):
        g, r = s["guard"], rec.frames[i]["/guard/status"][-1]
        assert g["tick"] == s["tick"] and not g["stale"] and g["why"] is None
        assert g["distance_mm"] == pytest.approx(r["distance_mm"], abs=1e-3)
        assert g["pair"] == [{"arm": r["a_arm"], "body": r["a_body"]}, {"arm": r["b_arm"], "body": r["b_body"]}]
        assert np.allclose(g["points"], [r["a_point_mm"], r["b_point_mm"]], atol=0.01)
        assert g["override"] == {"arm1": pytest.approx(r["override"][0], abs=1e-3),
                                 "arm2": pytest.approx(r["override"][1], abs=1e-3)}
        if g["state"] == "stopped":
            assert set(g["override"].values()) == {0.0} and g["trips"] == 1
    slow = next(s["guard"] for s in src.snaps if s["guard"]["state"] == "slowing")
    assert 0.0 < min(slow["override"].values()) < 1.0
    assert {b["arm"] for b in src.snaps[-1]["guard"]["pair"]} == {"arm1", "arm2"}  # at the end: the arms' links
    # served: /api/frame carries it (strict JSON: no NaN or Infinity in the page's data)
    with WebServer("--file", recording) as w:
        f = w.get(f"api/frame?i={len(src.snaps) - 1}")
    assert f["guard"]["state"] == "stopped" and len(f["guard"]["points"]) == 2


def test_droid_foxglove_draws_the_closest_pair_of_a_recording(recording):
    """droid-foxglove's feed: /guard (the page's view), /guard/status (the record) and
    /guard/closest, a line [m] between the two closest points, red when stopped."""
    from droid.observe.foxglove import GUARD_COLORS, FileFeedSource, FoxgloveFeed

    src = FileFeedSource(recording)
    feed = FoxgloveFeed(src.meta)
    topics = feed.topics()
    assert topics["/guard/closest"] == "foxglove.SceneUpdate" and topics["/guard"]["title"] == "droid.guard_view"
    assert topics["/guard/status"]["title"] == "droid.guard_status"
    states = set()
    for i in range(len(src.rec.ticks)):
        st = src.statuses(i)
        msgs = feed.step(src.rec.ticks[i], 10**18, st, now_s=float(i))
        g = msgs["/guard"]
        states.add(g["state"])
        assert msgs["/guard/status"]["_subunit"] == "guard" and msgs["/guard/status"]["tick"] == g["tick"]
        (ent,) = msgs["/guard/closest"]["entities"]
        (line,) = ent["lines"]
        pts = [[p["x"] * 1000.0, p["y"] * 1000.0, p["z"] * 1000.0] for p in line["points"]]
        assert np.allclose(pts, [st["guard"]["a_point_mm"], st["guard"]["b_point_mm"]], atol=0.02)
        assert line["color"] == GUARD_COLORS[g["state"]]
    assert states == {"clear", "slowing", "stopped"}


def test_off_where_no_droid_guard_writes_the_status(tmp_path):
    """``run = false`` (the record made, nothing writes it), a cell without ``[guard]``, a record not
    yet written, a recording without one: ``off`` and why -- no zeros, no line."""
    from droid.observe.foxglove import FileFeedSource, FoxgloveFeed
    from droid.observe.sources import FileSource
    from droid.observe.view import guard_view

    off = guard_recording(tmp_path / "off.mcap", run=False)
    for s in FileSource(off).snaps:
        g = s["guard"]
        assert g["state"] == "off" and "run = false" in g["why"]
        assert g["distance_mm"] is None and g["points"] is None and g["override"] == {}
    src = FileFeedSource(off)
    feed = FoxgloveFeed(src.meta)
    assert "/guard/status" not in feed.topics()
    msgs = feed.step(src.rec.ticks[0], 10**18, src.statuses(0), now_s=0.0)
    assert msgs["/guard"]["state"] == "off" and msgs["/guard/closest"]["entities"][0]["lines"] == []
    assert "/guard/status" not in msgs
    seam = FileSource(lockstep_recording(tmp_path / "seam.mcap"))  # a lockstep seam trial: no guard
    assert seam.snaps[-1]["guard"]["state"] == "off" and seam.snaps[-1]["guard"]["why"]
    assert guard_view({"declared": False, "run": False}, None)["why"].startswith("no [guard] table")
    on = {"declared": True, "run": True}
    assert guard_view(on, {"tick": 0, "state": 0, "distance_mm": 0.0})["state"] == "off"  # never written
    assert guard_view(on, None)["state"] == "off"


def test_a_guard_record_behind_the_arms_is_stale():
    from droid.observe.view import guard_view

    d = {"tick": 100, "state": 0, "distance_mm": 300.0, "stale_ticks": 6, "n_arms": 1, "arms": ["arm1"],
         "override": [1.0], "a_arm": "arm1", "a_body": "tool", "b_arm": "fixture", "b_body": "floor",
         "a_point_mm": [0.0, 0.0, 300.0], "b_point_mm": [math.nan, 0.0, 0.0]}
    on = {"declared": True, "run": True}
    assert not guard_view(on, d, 106)["stale"] and guard_view(on, d, 107)["stale"]
    assert guard_view(on, d, 100)["points"] is None  # a NaN point: no line
