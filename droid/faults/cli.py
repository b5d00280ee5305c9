"""droid-fault: inject faults into a running DROID cell (issue 8; docs/safety.md).

Links (through a fault proxy on an endpoint of the cell file)::

    droid-fault list                                 # endpoints and programs of the cell
    droid-fault interpose arm1.agent >> cell.toml    # the [interpose] entry a proxy needs
    droid-fault proxy arm1.agent --drop 0.1 --seed 3 # run the proxy (foreground)
    droid-fault set arm1.agent --delay-ms 40 --duplicate 0.2
    droid-fault set arm1.agent --clear
    droid-fault cut arm1 / droid-fault restore arm1  # blackhole every proxied endpoint of a host
    droid-fault interpose abb.egm >> cell.toml       # an ABB arm's EGM link (UDP) too
    droid-fault set abb.egm --drop 0.05 --jitter-ms 8

Programs (found through droid-cell status)::

    droid-fault kill "droid-servo arm1"      # SIGKILL; bring it back: droid-cell restart
    droid-fault pause droid-planner.arm1     # SIGSTOP (by name or key)
    droid-fault resume droid-planner.arm1    # SIGCONT

Network namespaces (a two-host cell, droid.faults.netns)::

    droid-fault link NS DEV down|up

Exit codes: 0 ok, 2 bad input, 1 runtime failure (no proxy answers, the
program is not running, a proxy's port is in use, ip failed).
"""
from __future__ import annotations

import json
import sys

from droid.brain.cell.cellfile import load_cell
from droid.brain.runtime.program import Stop
from droid.brain.runtime.rt import try_sched_fifo
from droid.cli import ArgumentParser, BadInput, DroidError, bounded_float, run, seed_int
from droid.faults import procs
from droid.faults.core import MAX_LINK_DELAY_MS, LinkFaults
from droid.faults.proxy import FaultProxy, cell_endpoints, control, endpoint, interpose_table

PROG = "droid-fault"


_probability = bounded_float(0.0, 1.0)
_delay_ms = bounded_float(0.0, MAX_LINK_DELAY_MS, "ms")  # LinkFaults' range, refused before the cell is read


def _add_link_faults(p) -> None:
    p.add_argument("--drop", type=_probability, help="probability a message is lost")
    p.add_argument("--duplicate", type=_probability, help="probability a message is delivered twice")
    p.add_argument("--delay-ms", type=_delay_ms, help="delay added to every message [ms]")
    p.add_argument("--jitter-ms", type=_delay_ms, help="uniform extra delay 0..J [ms]")


def _faults_from(args) -> dict:
    d = {k: getattr(args, k) for k in ("drop", "duplicate", "delay_ms", "jitter_ms") if getattr(args, k) is not None}
    if getattr(args, "cut", None) is not None:
        d["cut"] = args.cut
    return d


def build_parser() -> ArgumentParser:
    ap = ArgumentParser(prog=PROG, description="Inject faults into a running DROID cell: lossy, late or "
                        "duplicated links, killed or paused programs, hosts cut off.")
    ap.add_argument("--cell", metavar="FILE", default=None,
                    help="cell file (default: $DROID_CELL, else the built-in simulated cell)")
    sp = ap.add_subparsers(dest="cmd", required=True,
                           metavar="{list,interpose,proxy,set,cut,restore,kill,pause,resume,link}")
    p = sp.add_parser("list", help="the cell's endpoints and programs")
    p.add_argument("--json", action="store_true", help="one JSON object a line")
    p = sp.add_parser("interpose", help="print the [interpose] table that lets a proxy serve these endpoints")
    p.add_argument("labels", nargs="+", metavar="LABEL", help="endpoint label, e.g. arm1.agent")
    p = sp.add_parser("proxy", help="run a fault proxy on one endpoint (until SIGTERM)")
    p.add_argument("label", help="endpoint label, e.g. arm1.agent (droid-fault list)")
    _add_link_faults(p)
    p.add_argument("--seed", type=seed_int, default=0, help="seed of the per-message decisions (default 0)")
    p = sp.add_parser("set", help="change the faults of a running proxy")
    p.add_argument("label")
    _add_link_faults(p)
    p.add_argument("--cut", action="store_true", default=None, help="drop everything (both ways)")
    p.add_argument("--clear", action="store_true", help="back to a clean link first")
    for name, hlp in (("cut", "blackhole every proxied endpoint of a host"), ("restore", "undo 'cut'")):
        p = sp.add_parser(name, help=hlp)
        p.add_argument("host")
    for name in ("kill", "pause", "resume"):
        p = sp.add_parser(name, help={"kill": "SIGKILL a program", "pause": "SIGSTOP a program",
                                      "resume": "SIGCONT a program"}[name])
        p.add_argument("program", help="as droid-cell status lists it ('droid-servo arm1') or its key")
    p = sp.add_parser("link", help="set a veth of a network namespace down or up (a two-host cell)")
    p.add_argument("netns")
    p.add_argument("dev")
    p.add_argument("state", choices=("down", "up"))
    return ap


def _list(cell, args) -> int:
    """The cell's endpoints (interposed or not), then its running programs when the cell is up."""
    for e in cell_endpoints(cell).values():
        row = {"endpoint": e.label, "public": e.public, "kind": e.kind, "host": e.host,
               "interposed": cell.bind_endpoint(e.public) != e.public}
        print(json.dumps(row) if args.json else
              f"{e.label:<20} {e.kind:<6} host {e.host:<6} {e.public}{'  (interposed)' if row['interposed'] else ''}")
    try:
        rows = procs.programs(cell)
    except DroidError:  # the cell is not up: endpoints only
        rows = []
    for r in rows:
        print(json.dumps({"program": r["name"], "key": r["key"], "pid": r["pid"], "live": r["live"]})
              if args.json else f"{r['name']:<28} key {r['key']:<24} pid {r['pid']}")
    return 0


def _interpose(cell, args) -> int:
    sys.stdout.write(interpose_table(cell, args.labels))
    return 0


def _proxy(cell, args) -> int:
    """Run a fault proxy on one endpoint until SIGTERM; print its counts."""
    proxy = FaultProxy(cell, args.label, LinkFaults.from_dict(_faults_from(args)), seed=args.seed)
    Stop.install()
    # the proxy stands in for a wire: it runs at the priority of the programs it sits between
    try_sched_fifo(wanted=cell.sched_fifo, prog=PROG)
    proxy.serve(stop=lambda: Stop.requested, on_ready=lambda: print(
        f"{PROG}: proxy on {args.label} ({proxy.ep.public} -> {proxy.inner}), control {proxy.control}",
        file=sys.stderr, flush=True))
    print(json.dumps(proxy.counts()))
    return 0


def _set(cell, args) -> int:
    """Change a running proxy's faults (``--clear``: from a clean link)."""
    endpoint(cell, args.label)
    d = _faults_from(args)
    if args.clear:
        d = {**LinkFaults().as_dict(), **d}
    LinkFaults.from_dict(d)  # bad values: exit 2 here, not in the proxy
    ans = control(cell, args.label, {"set": d})
    if not ans.get("ok"):
        raise BadInput(ans.get("error", "refused"))
    print(json.dumps(ans))
    return 0


def _cut_or_restore(cell, args) -> int:
    """Blackhole (or restore) every interposed endpoint of a host."""
    labels = [e.label for e in cell_endpoints(cell).values()
              if e.host == args.host and cell.bind_endpoint(e.public) != e.public]
    if args.host not in cell.hosts():
        raise BadInput(f"unknown host {args.host!r} (cell hosts: {', '.join(cell.hosts())})")
    if not labels:
        raise BadInput(f"no endpoint of host {args.host} is interposed (droid-fault interpose ...)")
    for label in labels:
        ans = control(cell, label, {"set": {"cut": args.cmd == "cut"}})
        print(json.dumps(ans))
    return 0


def _signal(cell, args) -> int:
    """kill / pause / resume a program: SIGKILL, SIGSTOP, SIGCONT."""
    pid = procs.signal_program(cell, args.program, args.cmd)
    print(f"{PROG}: {args.cmd} {args.program} (pid {pid})")
    return 0


def _link(cell, args) -> int:
    from droid.faults.netns import ip

    ip("-n", args.netns, "link", "set", args.dev, args.state)
    return 0


_COMMANDS = {"list": _list, "interpose": _interpose, "proxy": _proxy, "set": _set, "cut": _cut_or_restore,
             "restore": _cut_or_restore, "kill": _signal, "pause": _signal, "resume": _signal, "link": _link}


@run
def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    cell = load_cell(args.cell)
    command = _COMMANDS.get(args.cmd)
    return command(cell, args) if command is not None else 2


if __name__ == "__main__":
    sys.exit(main())
