"""Cell files for fault experiments: the Reis alone, on one host behind a fault proxy
(the campaign), or split over two hosts (network namespaces, tcp)."""
from __future__ import annotations


def _reis_cell_text(name: str, run_dir: str, brain_extra: str = "", arm_extra: str = "", tail: str = "") -> str:
    """The Reis alone (with the world) on host arm1, the Brain on host brain; the extras add
    endpoint lines to [brain] and [subunits.arm1] and tables at the end."""
    return f'''
[cell]
name = "{name}"
run_dir = "{run_dir}"
heartbeat_hz = 60.0
stale_ticks = 3
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
    return _reis_cell_text(name, run_dir, tail='''
[interpose]
"ipc://{run}/arm1.agent" = "ipc://{run}/arm1.agent.inner"
''')


def two_host_cell_text(name: str, run_dir: str, brain_addr: str, arm_addr: str) -> str:
    """arm1 (Reis) on host arm1 with the world; the Brain on host brain; tcp between them."""
    return _reis_cell_text(
        name, run_dir,
        brain_extra=f'heartbeat = "tcp://{brain_addr}:5551"\nnames = "tcp://{brain_addr}:5550"\n',
        arm_extra=f'agent = "tcp://{arm_addr}:5552"\nrelay = "ipc://{{run}}/arm1.relay"\n')


def seam_campaign_cell_text(name: str, run_dir: str) -> str:
    """The built-in seam-tracking cell (both arms, the MVS and tool sensors) with arm1's
    agent link behind a fault proxy, as in :func:`campaign_cell_text`."""
    import re

    from droid.brain.cellfile import builtin_cell_path

    text = builtin_cell_path().read_text()
    text, n = re.subn(r'(?m)^name = "[^"]*"', f'name = "{name}"\nrun_dir = "{run_dir}"', text, count=1)
    if n != 1:
        raise RuntimeError("the built-in cell has no [cell] name line")
    return text + '''
[interpose]
"ipc://{run}/arm1.agent" = "ipc://{run}/arm1.agent.inner"
'''
