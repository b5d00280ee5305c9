"""Cell files for fault experiments: the Reis alone, on one host behind a fault proxy
(the campaign), or split over two hosts (network namespaces, tcp)."""
from __future__ import annotations


#: The campaign's silence rule [heartbeat ticks]: the thesis's 3 (50 ms), which the fault
#: table of docs/safety.md counts in.
CAMPAIGN_STALE_TICKS = 3
#: The two-host cell's [heartbeat ticks]: the shipped cells' 12 (200 ms), set against this VM's
#: host stalls.  At 3 the watchdog's servo-liveness rule is 60 ms, and a stall of the servo's
#: CPU that long latched the amplifiers while the arm homed, before any cut (CI, 2026-12-03:
#: the servo missed 96 of 1041 periods in 2.1 s).  How the arm stops at a cut does not depend
#: on it (the servo agent brakes 1.5 periods after the last tick); when the link is declared
#: lost does (docs/safety.md section 4).
TWO_HOST_STALE_TICKS = 12


def _one_arm_cell_text(name: str, run_dir: str, brain_extra: str = "", arm_extra: str = "", tail: str = "",
                       stale_ticks: int = CAMPAIGN_STALE_TICKS) -> str:
    """The Reis alone (with the world) on host arm1, the Brain on host brain; the extras add
    endpoint lines to [brain] and [subunits.arm1] and tables at the end; ``stale_ticks``
    [heartbeat ticks] is the cell's silence rule."""
    return f'''
[cell]
name = "{name}"
run_dir = "{run_dir}"
heartbeat_hz = 60.0
stale_ticks = {stale_ticks}
sched_fifo = true

[brain]
host = "brain"
{brain_extra}
[world]
enabled = true
host = "arm1"
rate_hz = 1000.0
seed = 1

[world.devices.arm1]
type = "reis_vme"
subunit = "arm1"

[subunits.arm1]
class = "arm6r"
robot = "reis_v15"
host = "arm1"
{arm_extra}programs = ["droid-watchdog", "droid-servo", "droid-servo-agent", "droid-reis-agent", "droid-planner"]
vme = "shm://droid.{{cell}}.arm1.vme"
servo = "ipc://{{run}}/arm1.servo"
servo_status = "ipc://{{run}}/arm1.servostat"
{tail}'''


def campaign_cell_text(name: str, run_dir: str) -> str:
    """A one-host cell with the Reis alone, its agent link behind a fault proxy."""
    return _one_arm_cell_text(name, run_dir, tail='''
[interpose]
"ipc://{run}/arm1.agent" = "ipc://{run}/arm1.agent.inner"
''')


def two_host_cell_text(name: str, run_dir: str, brain_addr: str, arm_addr: str,
                       stale_ticks: int = TWO_HOST_STALE_TICKS) -> str:
    """arm1 (Reis) on host arm1 with the world; the Brain on host brain; tcp between them;
    ``stale_ticks`` [heartbeat ticks] as TWO_HOST_STALE_TICKS unless given."""
    return _one_arm_cell_text(
        name, run_dir,
        brain_extra=f'heartbeat = "tcp://{brain_addr}:5551"\nnames = "tcp://{brain_addr}:5550"\n',
        arm_extra=f'agent = "tcp://{arm_addr}:5552"\nrelay = "ipc://{{run}}/arm1.relay"\n',
        stale_ticks=stale_ticks)


def seam_campaign_cell_text(name: str, run_dir: str) -> str:
    """The built-in seam-tracking cell (both arms, the MVS and tool sensors) with arm1's
    agent link behind a fault proxy, as in :func:`campaign_cell_text`."""
    import re

    from droid.brain.cell.cellfile import builtin_cell_path

    text = builtin_cell_path().read_text()
    text, n = re.subn(r'(?m)^name = "[^"]*"', f'name = "{name}"\nrun_dir = "{run_dir}"', text, count=1)
    if n != 1:
        raise RuntimeError("the built-in cell has no [cell] name line")
    return text + '''
[interpose]
"ipc://{run}/arm1.agent" = "ipc://{run}/arm1.agent.inner"
'''
