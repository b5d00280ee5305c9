"""Where droid-web's snapshots come from: a running cell's databases, or a recording (docs/observe.md).

:class:`LiveSource` reads the Brain's databases (read-only, like a task) and
builds a snapshot on demand; :class:`FileSource` reads a whole recording and
serves the snapshot at any index (the page's time slider).  Both give
``meta`` (the recording's ``droid`` metadata, or the same built from the cell),
``status()`` (``/api/status``) and ``close()``.
"""
from __future__ import annotations

import time

from droid.cli import BadInput
from droid.observe import schemas
from droid.observe.mcapfile import TOPIC_HEALTH, TOPIC_LOG, cell_meta, read_recording
from droid.observe.scene import live_workpiece_mesh, scene_meta
from droid.observe.view import ViewBuilder

HEALTH_PERIOD_S = 0.5  # program health at most twice a second
LOG_TAIL = 30  # events kept for the page


class LiveSource:
    """Snapshots of a running (or replay) cell's Brain databases."""

    mode = "live"

    def __init__(self, cell) -> None:
        from droid.observe.sampler import CellSampler

        self.cell = cell
        self.meta = cell_meta(cell, "live", scene_meta(cell))
        mesh = live_workpiece_mesh(cell)  # a simulated cell's workpiece shape (droid-sim publishes it)
        if mesh is not None:
            self.meta["scene"]["workpiece_mesh"] = mesh
        self.sampler = CellSampler(cell).connect()
        self.view = ViewBuilder(self.meta)
        from droid.observe.events import EventWatcher

        self.events = EventWatcher({s.name for s in cell.subunits.values() if s.is_arm})
        self.logs: list[dict] = []
        self._health: dict = {}
        self._health_t = 0.0
        self._tick = 0
        self.last: dict | None = None

    def health(self) -> dict:
        from droid.observe.sampler import health

        now = time.monotonic()
        if now - self._health_t >= HEALTH_PERIOD_S:
            self._health_t = now
            self._health = health(self.cell)
            self._log(self.events.health(self._health.get("programs", [])), self._tick)
        return self._health

    def _log(self, found, tick: int) -> None:
        for level, name, msg in found:
            self.logs.append({"tick": tick, "level": level, "name": name, "message": msg})
        del self.logs[:-LOG_TAIL]

    def statuses(self) -> dict[str, dict]:
        return {s: schemas.record_to_dict(r) for s, a, _, r in self.sampler.read() if a == "status"}

    def snapshot(self) -> dict:
        st = self.statuses()
        tick = self._tick = max((int(d.get("tick", 0)) for d in st.values()), default=0)
        self._log(self.events.step(st), tick)
        self.last = self.view.snapshot(tick, time.time_ns(), st, self.health())
        self.last["logs"] = list(self.logs)
        return self.last

    def status(self) -> dict:
        return {n: dict(schemas_status(d), subunit=n) for n, d in self.statuses().items()}

    def close(self) -> None:
        self.sampler.close()


def schemas_status(d: dict) -> dict:
    """A Status dict for /api/status: its payload fields (the header's bookkeeping left out)."""
    return {k: v for k, v in d.items() if k not in schemas.HEADER_KEEP or k == "seq"}


class FileSource:
    """Snapshots of a recording, by index (the page's time slider)."""

    mode = "file"

    def __init__(self, path: str) -> None:
        self.rec = read_recording(path)
        self.meta = self.rec.meta
        view = ViewBuilder(self.meta)
        self.snaps: list[dict] = []
        health: dict = {}
        logs: list[dict] = []
        self.log_n: list[int] = []
        self.logs = logs
        for i, tick in enumerate(self.rec.ticks):
            fr = self.rec.frames[i]
            st = {t.split("/")[1]: m[-1] for t, m in fr.items() if t.endswith("/status") and t.count("/") == 2}
            if TOPIC_HEALTH in fr:
                health = {k: v for k, v in fr[TOPIC_HEALTH][-1].items() if k != "_tick"}
            logs.extend({"tick": m["_tick"], "level": m["level"], "name": m["name"], "message": m["message"]}
                        for m in fr.get(TOPIC_LOG, []))
            self.log_n.append(len(logs))
            self.snaps.append(view.snapshot(tick, self.rec.t_ns[i], st, health))
        self.seam = view.seam
        if not self.snaps:
            raise BadInput(f"{path}: the recording holds no tick")
        self.index = len(self.snaps) - 1

    def frame(self, i: int, seam_from: int = 0) -> dict:
        """The snapshot at index ``i``, with the seam map's points from ``seam_from`` on (the page asks
        only for those it lacks; ``seam_from`` past the snapshot's seam: from 0)."""
        i = min(max(0, i), len(self.snaps) - 1)
        self.index = i
        s = dict(self.snaps[i], index=i)
        n = s["geo"]["seam_n"]
        k = seam_from if seam_from <= n else 0
        s["seam"] = self.seam[k:n]
        s["seam_from"] = k
        s["logs"] = self.logs[max(0, self.log_n[i] - LOG_TAIL): self.log_n[i]]
        return s

    def status(self) -> dict:
        i = self.index
        fr = self.rec.frames[i]
        return {t.split("/")[1]: dict(schemas_status(m[-1]), subunit=t.split("/")[1])
                for t, m in fr.items() if t.endswith("/status") and t.count("/") == 2}

    def close(self) -> None:
        pass
