"""Faults and events from successive snapshots (the ``/log`` channel, foxglove.Log).

:class:`EventWatcher` is pure: it compares each subunit's Status dict and each
program's health row with the previous one and returns the changes worth a
line -- a fault bit set or cleared (FAULT_* of Table 3.1's additions), a
subunit going stale or fresh, homed, a command refused or failed
(``cmd_result``), a change of command mode, a sensor's data turning
invalid, a program changing state or dying, and heartbeat ticks missed.
"""
from __future__ import annotations

from droid.brain.db.layouts import CMD_FAILED, CMD_MODE_NAMES, CMD_REFUSED, FAULT_NAMES
from droid.observe.mcapfile import LOG_ERROR, LOG_INFO, LOG_WARNING


class EventWatcher:
    """Detects events between snapshots; ``step`` returns ``[(level, name, message)]``."""

    def __init__(self, arms: set[str]) -> None:
        self.arms = set(arms)
        self.prev: dict[str, dict] = {}
        self.prev_health: dict[str, dict] = {}

    def step(self, statuses: dict[str, dict], missed: int = 0) -> list[tuple[int, str, str]]:
        out: list[tuple[int, str, str]] = []
        if missed:
            out.append((LOG_WARNING, "heartbeat", f"{missed} heartbeat tick(s) missed"))
        for name, d in statuses.items():
            p = self.prev.get(name)
            self.prev[name] = d
            if p is None:
                continue
            arm = name in self.arms
            f_old, f_new = int(p.get("fault", 0)), int(d.get("fault", 0))
            for bit, fname in FAULT_NAMES.items():
                if f_new & bit and not f_old & bit:
                    out.append((LOG_ERROR, name, f"fault {fname} set"))
                elif f_old & bit and not f_new & bit:
                    out.append((LOG_INFO, name, f"fault {fname} cleared"))
            if d.get("stale") != p.get("stale"):
                out.append((LOG_WARNING, name, "stale") if d.get("stale") else (LOG_INFO, name, "fresh again"))
            if d.get("homed") != p.get("homed"):
                if arm:
                    out.append((LOG_INFO, name, "homed" if d.get("homed") else "not homed"))
                else:
                    out.append((LOG_WARNING, name, "data invalid") if d.get("homed") else (LOG_INFO, name, "data valid"))
            if arm and d.get("cmd_mode") != p.get("cmd_mode"):
                old, new = (CMD_MODE_NAMES.get(int(x.get("cmd_mode", -1)), str(x.get("cmd_mode"))) for x in (p, d))
                out.append((LOG_INFO, name, f"mode {old} -> {new}"))
            res = d.get("cmd_result")
            if arm and (res != p.get("cmd_result") or d.get("cmd_id") != p.get("cmd_id")):
                if res == CMD_REFUSED:
                    out.append((LOG_WARNING, name, f"command {d.get('cmd_id')} refused"))
                elif res == CMD_FAILED:
                    out.append((LOG_ERROR, name, f"command {d.get('cmd_id')} failed"))
        return out

    def health(self, rows: list[dict]) -> list[tuple[int, str, str]]:
        out = []
        for r in rows:
            p = self.prev_health.get(r["name"])
            self.prev_health[r["name"]] = r
            if p is None:
                continue
            if r.get("state") != p.get("state"):
                lvl = LOG_ERROR if r.get("state") in ("dead", "failed") else LOG_INFO
                out.append((lvl, r["name"], f"program {p.get('state')} -> {r.get('state')}"))
            if (r.get("bad_frames") or 0) > (p.get("bad_frames") or 0):
                out.append((LOG_WARNING, r["name"], f"{r['bad_frames'] - (p.get('bad_frames') or 0)} bad frame(s) dropped"))
        return out
