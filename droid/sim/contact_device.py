"""World twin ``type = "contact"``: a workpiece whose surfaces push on an arm's tool (issue 27
item 4; thesis §7.3; docs/contact.md).

A cell file puts a workpiece under an arm's tool, either fixed in the cell or held on
another arm's wrist (the seam-tracking layout's GMF1: the surface then moves with the
holder)::

    [world.devices.touch]
    type = "contact"
    tool_robot = "arm1"                       # a Reis twin declared before (its plant takes the push)
    workpiece = "step_input"                  # a workpiece with a [contact] table
    holder_robot = "gmf1_karel"               # the workpiece rides on this arm twin's wrist ...
    workpiece_mount = [x, y, z, A, B, C]      # ... at T_wcp_workpiece (mm, ZYZ deg)
    # or, instead of the two keys above:  workpiece_pose = [x, y, z, A, B, C]  (global T W, fixed)
    touch_pose = [0, 0, 235, -90, 90, 180]    # T_wcp_touch: the point that touches (mm, ZYZ deg)
    max_closing_speed_mm_s = 5000             # the skip-while-far bound (droid.sim.contact.ToolContact)
    plate_mm = 5                              # the plates' thickness: deeper is behind them, no push

The device attaches a :class:`droid.sim.contact.ToolContact` to the tool arm's plant at
build time (the plant asks it at each step) and detaches it on close; it has no step of
its own.  The F/T twin on the same arm reads the contact wrench through the arm device's
``contact_wrench_N_Nm()``.  Each fault is one line naming the table and the key.
"""
from __future__ import annotations

import sys
from typing import Any

from droid.sim.device import Device
from droid.sim.device_options import DeviceOptions

#: The default touching point: the seam layout's torch, 15 mm back from its wire tip along the
#: tool axis -- the gas nozzle (ASSUMED contact-tip-to-work distance; docs/contact.md).
DEFAULT_TOUCH_POSE = [0.0, 0.0, 235.0, -90.0, 90.0, 180.0]
#: No tool point and workpiece close faster than this [mm/s] (ASSUMED: the Reis arm's tool at
#: full joint speed, with a margin; the holder's motion included).
DEFAULT_MAX_CLOSING_SPEED_MM_S = 5000.0
#: The plates' thickness [mm] (ASSUMED: the step track is a plastic C-channel, thesis §6.1.1;
#: its wall taken as 5 mm).  A tool point deeper under a surface is behind the plate.
DEFAULT_PLATE_MM = 5.0


class ContactDevice(Device):
    """The contact's place in the world: built, it pushes on ``arm``'s plant; closed, it stops."""
    step_s = 0.004  # it only tells touches and releases: the contact itself is in the arm's plant step

    def __init__(self, name: str, arm, contact, log=None) -> None:
        self.name = name
        self.arm = arm
        self.contact = contact
        self.touching = False
        self.touches = 0  # how many times the tool came into contact
        self._log = log
        arm.plant.contact = contact

    def advance(self, dt_s: float) -> None:
        """The arm's plant asks the contact in its own step; here each touch and release is told
        on stderr (one line each: a run whose tool brushed the workpiece says so)."""
        touching = bool(self.contact.force_N.any())
        if touching != self.touching:
            self.touching = touching
            self.touches += touching
            if self._log is not None:
                t = getattr(self.arm.plant, "time_s", float("nan"))
                what = "touches" if touching else "leaves"
                self._log(f"droid-sim: {self.name}: {self.arm.name}'s tool {what} {self.contact.workpiece.name} "
                          f"at world time {t:.3f} s")

    def close(self) -> None:
        if getattr(self.arm.plant, "contact", None) is self.contact:
            self.arm.plant.contact = None


def make_contact(world, name: str, options: dict[str, Any]) -> ContactDevice:
    """Factory for ``type = "contact"`` (the module docstring)."""
    from droid.sim.contact import ToolContact
    from droid.sim.workpiece import load_workpiece

    opts = DeviceOptions(world, name, options)
    arm = opts.device("tool_robot", "arm twin with a plant that takes contact", "contact_wrench_N_Nm")
    plant = getattr(arm, "plant", None)
    if plant is None or not hasattr(plant, "contact"):
        raise opts.bad(f"device {opts.get('tool_robot', str)!r} has no plant that takes contact", "tool_robot")
    if plant.contact is not None:
        raise opts.bad(f"device {opts.get('tool_robot', str)!r} already has a contact "
                       f"(its own contact_workpiece, or another contact device)", "tool_robot")
    wp = load_workpiece(opts.get("workpiece", str, "step_input"))
    if wp.contact is None:
        raise opts.bad(f"workpiece {wp.name} has no [contact] table (docs/contact.md)", "workpiece")
    fixed = "workpiece_pose" in opts.table
    held = "holder_robot" in opts.table or "workpiece_mount" in opts.table
    if fixed == held:
        raise opts.bad("give either workpiece_pose (fixed) or holder_robot with workpiece_mount (held)")
    if fixed:
        T_W = opts.pose("workpiece_pose")
    else:
        holder = opts.device("holder_robot")
        T_mount = opts.pose("workpiece_mount")

        def T_W():
            return holder.wcp_global() @ T_mount

    T_tool = opts.pose("touch_pose", DEFAULT_TOUCH_POSE)
    closing = opts.get("max_closing_speed_mm_s", float, DEFAULT_MAX_CLOSING_SPEED_MM_S,
                       check=lambda v: None if 0 < v <= 1e6 else "must be in (0, 1e6] mm/s")
    plate = opts.get("plate_mm", float, DEFAULT_PLATE_MM,
                     check=lambda v: None if 0 < v <= 1000 else "must be in (0, 1000] mm")
    opts.done()
    contact = ToolContact(wp, T_W, arm.model.base, T_tool, max_closing_speed_mm_s=closing, max_depth_mm=plate)
    return ContactDevice(name, arm, contact, log=lambda line: print(line, file=sys.stderr, flush=True))
