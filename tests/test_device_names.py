"""Roles, not brands, above the device packages (issue 43 item 3; docs/architecture.md, "Issue 43's
targets, measured").

The rule counted: a *line of code outside a device's own package that names a device*.

* The files: every ``droid/**/*.py`` except a device's own package, ``droid/subunits/<dev>/`` and
  ``droid/sim/<dev>/`` for the built-in devices ``reis``, ``gmf1``, ``mvs``, ``joystick``, ``ft``,
  ``abb`` (there the code implements the thesis's own hardware and names it).
* The tokens: Python identifiers (``tokenize`` NAME tokens: variables, attributes, parameters,
  functions, classes, the dotted parts of an import).  Comments, docstrings and every other string
  literal are not counted: a docstring cites the thesis's hardware, and a string is a name users
  see -- a subunit class (``"ft6"``, ``"joystick"``), a layout, a registry entry naming its package
  (``"reis": "droid.subunits.reis.device:PACKAGE"``), a command-line flag (``--joystick``), a CSV
  column or a channel (``"gmf1"``) -- which must not change under users' scripts.
* A line counts once when one of its identifiers contains, in any case, ``reis``, ``gmf1``,
  ``fanuc``, ``mvs``, ``joystick``, ``ft6`` or ``abb`` (``T_global_reis6``, ``geo.fanuc``,
  ``MvsStation``, ``from droid.sim.mvs.camera import ...``).
* Exempt (``EXEMPT``): ``droid/brain/db/layouts.py``, the registry of the wire layouts, where the
  joystick's and the force/torque sensor's layouts predate the device registry and stay because the
  drivers, the twins and the tests import them from there (docs/architecture.md, "Measured for the
  joystick").

``test_device_names_do_not_grow`` holds the count at ``MAX_LINES`` (the figure reached: none) and
prints every counted line when it grows.  A generic layer that needs a device's part reaches it
through the device registry by role (droid.brain.cell.registry.DevicePackage: the layout's
``tool_robot``, ``holder_robot`` and ``sensor`` and their packages' ``lockstep_models``; a package's
``proxy_endpoints``), never by importing the device's module.
"""
from __future__ import annotations

import io
import re
import tokenize
from pathlib import Path

DEVICE_TOKEN = re.compile(r"reis|gmf1|fanuc|mvs|joystick|ft6|abb", re.IGNORECASE)
DEVICE_PACKAGES = ("reis", "gmf1", "mvs", "joystick", "ft", "abb")
EXEMPT = {"droid/brain/db/layouts.py": "the wire layouts' registry (the joystick's and ft6's pre-registry layouts)"}
#: 166 lines at d8bd1d5 (188 with layouts.py), 45 after the tracker and the observers named roles,
#: 38 after the trial's cell moved to droid/sim, 6 after TrialGeometry's tool/holder models, the
#: fault campaign's tool robot and one-arm cell text, ArmChain.link_agent and the workpiece's own
#: seam_frame, 0 after the last six imports of a device's own modules went through the registry by
#: role: the trial's truth sensors are the ``lead`` lockstep model of the layout's sensor's package
#: (the MVS's LeadSensor, with its tool-tip sensor and camera noise), the fast arm's parameters
#: its own default (TrialConfig.fast_params None), and droid-fault's proxy asks every package for
#: its ``proxy_endpoints`` (the ABB's EGM address) and parses UDP with droid.brain.plumbing.udp
#: (docs/architecture.md, "Issue 43's targets, measured").
MAX_LINES = 0

ROOT = Path(__file__).resolve().parent.parent


def own_package(rel: str) -> bool:
    """Whether ``rel`` (a path relative to the repository, ``droid/sim/reis/plant.py``) is in a device's own package."""
    return any(rel.startswith(f"droid/{layer}/{dev}/") for layer in ("subunits", "sim") for dev in DEVICE_PACKAGES)


def device_lines(source: str) -> list[int]:
    """The line numbers (1-based) of ``source`` on which an identifier names a device (the module docstring's rule)."""
    lines = []
    for tok in tokenize.generate_tokens(io.StringIO(source).readline):
        if tok.type == tokenize.NAME and DEVICE_TOKEN.search(tok.string) and tok.start[0] not in lines:
            lines.append(tok.start[0])
    return lines


def counted(root: Path) -> list[str]:
    """Every counted line under ``root/droid``, as ``path:line: text``."""
    out = []
    for path in sorted((root / "droid").rglob("*.py")):
        rel = path.relative_to(root).as_posix()
        if own_package(rel) or rel in EXEMPT:
            continue
        text = path.read_text(encoding="utf-8")
        rows = text.splitlines()
        out += [f"{rel}:{n}: {rows[n - 1].strip()}" for n in device_lines(text)]
    return out


def test_device_names_do_not_grow():
    lines = counted(ROOT)
    assert len(lines) <= MAX_LINES, (f"{len(lines)} lines of code outside a device's package name a device "
                                     f"(at most {MAX_LINES}; name the role: tool, holder, lead, tip):\n"
                                     + "\n".join(lines))


def test_the_rule_counts_identifiers_not_docstrings_comments_or_strings(tmp_path):
    """The counter on a small tree: identifiers count, one per line; docstrings, comments, strings
    and a device's own package do not."""
    (tmp_path / "droid" / "tasks").mkdir(parents=True)
    (tmp_path / "droid" / "sim" / "reis").mkdir(parents=True)
    (tmp_path / "droid" / "tasks" / "t.py").write_text(
        '"""The Reis (thesis §3.1) and the GMF1."""\n'
        "# the reis_cmd of the listing\n"
        'FLAG = "--joystick"\n'
        "def f(T_global_reis6, geo):\n"
        "    return geo.fanuc, T_global_reis6\n"
        "from droid.sim.mvs.camera import MvsCamera\n", encoding="utf-8")
    (tmp_path / "droid" / "sim" / "reis" / "plant.py").write_text("reis_plant = 1\n", encoding="utf-8")
    assert counted(tmp_path) == ["droid/tasks/t.py:4: def f(T_global_reis6, geo):",
                                 "droid/tasks/t.py:5: return geo.fanuc, T_global_reis6",
                                 "droid/tasks/t.py:6: from droid.sim.mvs.camera import MvsCamera"]
