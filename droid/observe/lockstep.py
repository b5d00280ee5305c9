"""Recording a lockstep trial in the same MCAP layout as a live cell (issue 14, item 2).

A lockstep trial (``droid-experiment run --record``, droid/experiments/trial.py)
has no shared memory: its arm twin, sensors and seam-tracking core exchange
plain values.  :class:`TrialRecorder` fills the Brain's records from them --
``arm1`` Status (the Status pose and joints the task sees, eq. 4.1-4.2, as
x, y, z, R and encoder counts through the robot's gearing) and Command (the
cycle's cartesian command, ``cart_time_count`` 2 ticks), ``gmf1`` Status (the
holder, still), ``mvs`` Status (the lead reading: x depth, y lateral [mm], R
the roll, ``homed`` = 1 when invalid, Table 3.3) and ``tool`` Status (the
tool-tip sensor: x height, y lateral) -- and hands them to the same
:class:`~droid.observe.record.CellRecorder` droid-record uses, so one viewer
serves real-time and lockstep trials.  Message times are the virtual time [ns].
"""
from __future__ import annotations

import math

import numpy as np

from droid.brain.db.layouts import (ARM_COMMAND_LAYOUT, ARM_STATUS_LAYOUT, CARTSPACE, HOMED, NORMAL_MODE,
                                 SENSOR_STATUS_LAYOUT, new_record)
from droid.kinematics.transforms import T_to_pose, rotz
from droid.observe.mcapfile import RecordingWriter
from droid.observe.record import CellRecorder

CYCLE_TICKS = 2


def _pose_into(rec, T) -> None:
    rec["x"], rec["y"], rec["z"] = float(T[0, 3]), float(T[1, 3]), float(T[2, 3])
    rec["R"] = np.asarray(T)[:3, :3]


class TrialRecorder:
    """One lockstep trial into a recording: ``sample`` once per heartbeat tick, ``close`` at the end.

    ``tool_model``/``holder_model``: the tool robot's and the holder's models (bases included);
    ``T_wcp_tool``/``T_wcp_sensor``: the wrist; ``T_hold6_W``: the workpiece mount;
    ``q_hold_deg``/``T_hold``: the holder, still;
    ``workpiece_mesh``: the workpiece's surfaces in W for viewers (plain data, made by the trial's
    maker from the workpiece model: droid.sim.workpiece_mesh)."""

    def __init__(self, path: str, trial_id: str, tool_model, holder_model, T_wcp_tool, T_wcp_sensor, T_hold6_W,
                 q_hold_deg, T_hold, *, names=("arm1", "gmf1", "mvs", "tool"),
                 workpiece_mesh: dict | None = None) -> None:
        self.arm, self.hold, self.lead, self.tool = names
        self.tool_model, self.holder_model = tool_model, holder_model
        subs = [
            {"name": self.arm, "class": "arm6r", "robot": tool_model.name, "base": T_to_pose(tool_model.base).tolist(),
             "areas": {"status": _area(ARM_STATUS_LAYOUT), "command": _area(ARM_COMMAND_LAYOUT)}},
            {"name": self.hold, "class": "arm6r", "robot": holder_model.name,
             "base": T_to_pose(holder_model.base).tolist(),
             "areas": {"status": _area(ARM_STATUS_LAYOUT)}},
            {"name": self.lead, "class": "line_laser", "robot": None, "base": [0.0] * 6,
             "areas": {"status": _area(SENSOR_STATUS_LAYOUT)}},
            {"name": self.tool, "class": "line_laser", "robot": None, "base": [0.0] * 6,
             "areas": {"status": _area(SENSOR_STATUS_LAYOUT)}},
        ]
        scene = {"tool_robot": self.arm, "holder_robot": self.hold, "sensor": self.lead,
                 "T_wcp_tool": np.asarray(T_wcp_tool).tolist(), "T_wcp_sensor": np.asarray(T_wcp_sensor).tolist(),
                 "T_wcp_workpiece": np.asarray(T_hold6_W).tolist()}
        if workpiece_mesh is not None:  # the workpiece's surfaces in W (droid.sim.workpiece_mesh: plain data)
            scene["workpiece"] = workpiece_mesh.get("name")
            scene["workpiece_mesh"] = workpiece_mesh
        meta = {"cell": f"lockstep-{trial_id}", "heartbeat_hz": 60.0, "source": "lockstep", "trial": trial_id,
                "subunits": subs, "scene": scene}
        self.core = CellRecorder(RecordingWriter(path, meta))
        self.s_arm = new_record(ARM_STATUS_LAYOUT)
        self.c_arm = new_record(ARM_COMMAND_LAYOUT)
        self.s_hold = new_record(ARM_STATUS_LAYOUT)
        self.s_lead = new_record(SENSOR_STATUS_LAYOUT)
        self.s_tool = new_record(SENSOR_STATUS_LAYOUT)
        _pose_into(self.s_hold, T_hold)
        self.s_hold["encoder_pos"] = holder_model.gearing.joints_to_counts_int(np.asarray(q_hold_deg, float))
        self.s_hold["encoder_cmd"] = self.s_hold["encoder_pos"]
        for r in (self.s_arm, self.s_hold):
            r["homed"] = HOMED
            r["cmd_mode"] = NORMAL_MODE
            r["coord"] = CARTSPACE
        self.c_arm["cmd_mode"] = NORMAL_MODE
        self.c_arm["coord"] = CARTSPACE
        self._cycle = None

    def sample(self, tick: int, t_ns: int, arm, state: dict) -> None:
        """One tick: ``arm`` has ``status_pose()`` (4x4) and ``status_joints()`` [deg]; ``state`` holds
        ``lead`` (a Reading), ``tool`` (lateral_mm, height_mm, roll_rad, or None) and ``out`` (CycleOutput)."""
        for r in (self.s_arm, self.s_hold, self.s_lead, self.s_tool):
            r["tick"] = tick
            r["updated_ns"] = t_ns
        _pose_into(self.s_arm, arm.status_pose())
        if state.get("T_hold") is not None:  # the holder's Status pose (it moves in holder-moving trials)
            _pose_into(self.s_hold, state["T_hold"])
        self.s_arm["encoder_pos"] = self.tool_model.gearing.joints_to_counts_int(np.asarray(arm.status_joints(), float))
        out = state.get("out")
        if out is not None and out.tool_cmd is not None and out.cycle != self._cycle:
            self._cycle = out.cycle
            _pose_into(self.c_arm, out.tool_cmd)
            self.c_arm["cart_time_count"] = CYCLE_TICKS
            self.c_arm["cmd_id"] = out.cycle + 1
            self.c_arm["sent"] = 0
            self.s_arm["cmd_id"] = out.cycle + 1
            self.s_arm["busy"] = CYCLE_TICKS
            if out.q_tool_deg is not None:
                self.s_arm["encoder_cmd"] = self.tool_model.gearing.joints_to_counts_int(
                    np.asarray(out.q_tool_deg, float))
        lead = state.get("lead")
        if lead is not None:
            self.s_lead["x"], self.s_lead["y"] = lead.x_mm, lead.y_mm
            self.s_lead["R"] = rotz(lead.roll_rad)[:3, :3]
            self.s_lead["homed"] = 0 if lead.valid else 1
            self.s_lead["valid_count" if lead.valid else "invalid_count"] += 1
        tool = state.get("tool")
        if tool is None:
            self.s_tool["homed"] = 1
        else:
            self.s_tool["homed"] = 0
            self.s_tool["x"], self.s_tool["y"] = tool.height_mm, tool.lateral_mm
            self.s_tool["R"] = rotz(tool.roll_rad)[:3, :3] if math.isfinite(tool.roll_rad) else np.eye(3)
        recs = [(self.arm, "status", ARM_STATUS_LAYOUT, self.s_arm), (self.arm, "command", ARM_COMMAND_LAYOUT, self.c_arm),
                (self.hold, "status", ARM_STATUS_LAYOUT, self.s_hold), (self.lead, "status", SENSOR_STATUS_LAYOUT, self.s_lead),
                (self.tool, "status", SENSOR_STATUS_LAYOUT, self.s_tool)]
        self.core.sample(tick, t_ns, recs)
        if self.s_arm["busy"] > 0:
            self.s_arm["busy"] -= 1

    def close(self) -> None:
        self.core.close()


def _area(layout) -> dict:
    return {"layout": layout.name, "version": layout.version}
