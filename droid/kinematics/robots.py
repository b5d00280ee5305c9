"""Robot models as data: load a TOML robot file into a :class:`RobotModel`.

A robot of the OPW class (6R, spherical wrist — thesis §3, "most industrial
arms share the same kinematic model") is a file, not code.  Bundled files live
in ``droid/kinematics/robots/``; ``load_robot`` takes a bundled name
(``"reis_v15"``) or a path to a ``.toml`` file.  The file format is described
in docs/kinematics.md; every table and key is checked, unknown keys are
rejected (a typo must not silently become a default), every number must be
finite and inside its key's range (:func:`droid.numbers.check_numbers`: the
one leaf module of droid this package imports), and if a ``[dh]`` table is
present the ``[opw]`` parameters must reproduce its forward kinematics.
"""
from __future__ import annotations

import functools
import math
import os
import tomllib
from pathlib import Path

import numpy as np

from droid.numbers import BadFile, check_numbers

from .dh import DhTable, fk_dh
from .dynamics import axis_servo_from_table, dynamics_from_table, servo_from_table
from .gearing import Gearing
from .model import Geometry, RobotModel
from .opw import OpwParams
from .opw import fk as opw_fk

BUNDLED_DIR = Path(__file__).resolve().parent / "robots"

#: tolerance [mm, and unitless for rotation entries] of the [dh] vs [opw] check.
DH_CHECK_TOL = 1e-6
#: joint vectors used for the check (seeded, plus the zero pose).
DH_CHECK_SAMPLES = 32

_TOP_KEYS = {"name", "description", "assumed", "source", "dh", "opw", "gearing", "limits", "home", "planner",
             "servo", "dynamics", "axis_servo", "geometry"}
_KEYS = {
    "dh": {"convention", "theta_offset_deg", "d_mm", "a_mm", "alpha_deg"},
    "opw": {"a1_mm", "a2_mm", "b_mm", "c1_mm", "c2_mm", "c3_mm", "c4_mm", "offsets_deg", "signs"},
    "gearing": {"reduction", "encoder_counts_per_rev", "direction", "coupling", "encoder_bits"},
    "limits": {"joint_min_deg", "joint_max_deg", "counts_min", "counts_max", "vmax_deg_s"},
    "home": {"switch_deg", "search_dir"},
    "planner": {"weights"},
    "geometry": {"link_radius_mm", "visual_mesh", "collision_mesh"},
}
_REQUIRED = {
    "opw": {"c1_mm", "c2_mm", "c3_mm"},
    "gearing": {"reduction", "encoder_counts_per_rev"},
    "limits": {"joint_min_deg", "joint_max_deg", "vmax_deg_s"},
    "home": {"switch_deg"},
    "planner": {"weights"},
}


class RobotFileError(BadFile):
    """A robot name that is not bundled, or a robot file that is missing or malformed (a
    ValueError; every program's :func:`droid.cli.run` ends with its message and exit 2)."""


def list_robots() -> list[str]:
    """Names of the bundled robot files."""
    return sorted(p.stem for p in BUNDLED_DIR.glob("*.toml"))


def _resolve(name_or_path) -> Path:
    text = os.fspath(name_or_path)
    looks_like_path = text.endswith(".toml") or os.sep in text or (os.altsep and os.altsep in text)
    if looks_like_path:
        path = Path(text)
        if not path.is_file():
            raise RobotFileError(f"robot file not found: {text}")
        return path
    if not text or not all(ch.isalnum() or ch in "_-" for ch in text):
        raise RobotFileError(f"bad robot name {text!r}")
    path = BUNDLED_DIR / f"{text}.toml"
    if not path.is_file():
        raise RobotFileError(f"unknown robot {text!r} (bundled: {', '.join(list_robots())}; or give a .toml path)")
    return path


def load_robot(name_or_path) -> RobotModel:
    """Load a robot model from a bundled name or a ``.toml`` path.  Raises :class:`RobotFileError`."""
    path = _resolve(name_or_path)
    if path.parent.resolve() == BUNDLED_DIR:
        return _load_bundled(str(path))
    return _load_path(path)


@functools.lru_cache(maxsize=None)
def _load_bundled(path: str) -> RobotModel:
    return _load_path(Path(path))


def _load_path(path: Path) -> RobotModel:
    # Deliberately its own TOML reading (as droid-mvs's calibration loader): droid.kinematics
    # imports nothing else of droid (docs/design.md §7), so it raises its own RobotFileError.
    try:
        with open(path, "rb") as f:
            data = tomllib.load(f)
    except OSError as exc:
        raise RobotFileError(f"{path}: cannot read: {exc.strerror or exc}") from None
    except tomllib.TOMLDecodeError as exc:
        raise RobotFileError(f"{path}: not valid TOML: {exc}") from None
    try:
        return model_from_dict(data, source=str(path))
    except RobotFileError:
        raise
    except (ValueError, TypeError, KeyError) as exc:
        raise RobotFileError(f"{path}: {exc}") from None


def _table(data: dict, name: str) -> dict:
    t = data.get(name)
    if t is None:
        if name in ("dh", "geometry"):
            return {}
        raise ValueError(f"missing table [{name}]")
    if not isinstance(t, dict):
        raise ValueError(f"[{name}] must be a table")
    unknown = set(t) - _KEYS[name]
    if unknown:
        raise ValueError(f"[{name}]: unknown key(s) {', '.join(sorted(unknown))}")
    missing = _REQUIRED.get(name, set()) - set(t)
    if missing:
        raise ValueError(f"[{name}]: missing key(s) {', '.join(sorted(missing))}")
    return t


def _num(table: str, key: str, value) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise ValueError(f"[{table}] {key}: expected a finite number")
    return float(value)


def _six(table: str, key: str, value) -> list[float]:
    if not isinstance(value, list) or len(value) != 6:
        raise ValueError(f"[{table}] {key}: expected a list of 6 numbers")
    return [_num(table, key, v) for v in value]


def model_from_dict(data: dict, source: str = "") -> RobotModel:
    """Build a model from a parsed robot file (see docs/kinematics.md for the format)."""
    unknown = set(data) - _TOP_KEYS
    if unknown:
        raise ValueError(f"unknown key(s)/table(s) {', '.join(sorted(unknown))}")
    check_numbers(data)  # every number finite and inside its key's range (droid.numbers, issue 16)
    name = data.get("name")
    if not isinstance(name, str) or not name:
        raise ValueError("'name' must be a non-empty string")
    description = data.get("description", "")
    assumed = data.get("assumed", False)
    if not isinstance(description, str) or not isinstance(assumed, bool):
        raise ValueError("'description' must be a string and 'assumed' true/false")

    params = _opw_params(_table(data, "opw"))
    dh = _dh_table(_table(data, "dh"), params)
    gearing = Gearing.from_table(_table(data, "gearing"))
    lim = _table(data, "limits")
    qmin, qmax, cmin, cmax = _joint_limits(lim, gearing)

    home = _table(data, "home")
    planner = _table(data, "planner")
    dynamics = dynamics_from_table(data["dynamics"]) if "dynamics" in data else None
    servo = servo_from_table(data["servo"]) if "servo" in data else None
    axis_servo = axis_servo_from_table(data["axis_servo"]) if "axis_servo" in data else None
    if axis_servo is not None and dynamics is None:
        raise ValueError("[axis_servo]: needs a [dynamics] table (the loops drive the arm's dynamics)")
    geometry = _geometry(_table(data, "geometry"))
    # Alike in shape only: one keyword per RobotModel field, each filled once from its table.
    return RobotModel(
        name=name,
        description=description,
        assumed=assumed,
        opw=params,
        gearing=gearing,
        joint_min_deg=qmin,
        joint_max_deg=qmax,
        counts_min=cmin,
        counts_max=cmax,
        home_switch_deg=_six("home", "switch_deg", home["switch_deg"]),
        home_search_dir=_six("home", "search_dir", home.get("search_dir", [1] * 6)),
        vmax_deg_s=_six("limits", "vmax_deg_s", lim["vmax_deg_s"]),
        weights=_six("planner", "weights", planner["weights"]),
        dh=dh,
        source=source,
        dynamics=dynamics,
        servo_gains=servo,
        axis_servo=axis_servo,
        geometry=geometry,
    )


def _opw_params(o: dict) -> OpwParams:
    """``[opw]``: the OPW parameters [mm], joint offsets [deg] and signs."""
    return OpwParams(
        a1=_num("opw", "a1_mm", o.get("a1_mm", 0.0)),
        a2=_num("opw", "a2_mm", o.get("a2_mm", 0.0)),
        b=_num("opw", "b_mm", o.get("b_mm", 0.0)),
        c1=_num("opw", "c1_mm", o["c1_mm"]),
        c2=_num("opw", "c2_mm", o["c2_mm"]),
        c3=_num("opw", "c3_mm", o["c3_mm"]),
        c4=_num("opw", "c4_mm", o.get("c4_mm", 0.0)),
        offsets_deg=tuple(_six("opw", "offsets_deg", o.get("offsets_deg", [0.0] * 6))),
        signs=tuple(_six("opw", "signs", o.get("signs", [1] * 6))),
    )


def _dh_table(d: dict, params: OpwParams) -> DhTable | None:
    """``[dh]`` (standard D-H, thesis eq. 4.1), checked against ``[opw]``; None without it."""
    if not d:
        return None
    convention = d.get("convention", "standard")
    if convention != "standard":
        raise ValueError("[dh] convention: only 'standard' (Rz Tz Tx Rx, thesis eq. 4.1) is supported")
    for key in ("theta_offset_deg", "d_mm", "a_mm", "alpha_deg"):
        if key not in d:
            raise ValueError(f"[dh]: missing key {key}")
    dh = DhTable(
        theta_offset_deg=tuple(_six("dh", "theta_offset_deg", d["theta_offset_deg"])),
        d_mm=tuple(_six("dh", "d_mm", d["d_mm"])),
        a_mm=tuple(_six("dh", "a_mm", d["a_mm"])),
        alpha_deg=tuple(_six("dh", "alpha_deg", d["alpha_deg"])),
    )
    check_dh_matches_opw(dh, params)
    return dh


def _joint_limits(lim: dict, gearing: Gearing):
    """``[limits]``: joint limits [deg] and encoder limits [counts] (given, or the joint box's)."""
    qmin = np.array(_six("limits", "joint_min_deg", lim["joint_min_deg"]))
    qmax = np.array(_six("limits", "joint_max_deg", lim["joint_max_deg"]))
    if np.any(qmin >= qmax):
        raise ValueError("[limits]: joint_min_deg must be < joint_max_deg for every joint")
    if ("counts_min" in lim) != ("counts_max" in lim):
        raise ValueError("[limits]: give both counts_min and counts_max, or neither")
    if "counts_min" in lim:
        cmin = np.array(_six("limits", "counts_min", lim["counts_min"]))
        cmax = np.array(_six("limits", "counts_max", lim["counts_max"]))
    else:
        cmin, cmax = counts_box(gearing, qmin, qmax)
    return qmin, qmax, cmin, cmax


def _geometry(t: dict) -> Geometry:
    """The optional ``[geometry]`` table: capsule radii [mm] of links 1-6 (> 0) and mesh names
    (7 strings: base_link, link_1 .. link_6; "" keeps the capsule)."""
    radius = None
    if "link_radius_mm" in t:
        radius = tuple(_six("geometry", "link_radius_mm", t["link_radius_mm"]))
        if any(r <= 0 for r in radius):
            raise ValueError("[geometry] link_radius_mm: radii must be > 0 mm")
    meshes = {}
    for key in ("visual_mesh", "collision_mesh"):
        if key not in t:
            meshes[key] = None
            continue
        v = t[key]
        if not isinstance(v, list) or len(v) != 7 or not all(isinstance(x, str) for x in v):
            raise ValueError(f"[geometry] {key}: expected 7 strings (base_link, link_1 .. link_6; \"\" for none)")
        for x in v:
            if any(ch in x for ch in '<>"&') or any(ord(ch) < 32 for ch in x):
                raise ValueError(f"[geometry] {key}: {x!r} is not a file name or URI")
        meshes[key] = tuple(v)
    return Geometry(link_radius_mm=radius, **meshes)


def counts_box(gearing: Gearing, qmin_deg, qmax_deg) -> tuple[np.ndarray, np.ndarray]:
    """Encoder limits [counts] of the joint-limit box: its image's bounding box, rounded outward."""
    m = gearing.joint_to_counts_matrix
    lo = np.minimum(m * qmin_deg, m * qmax_deg).sum(axis=1)
    hi = np.maximum(m * qmin_deg, m * qmax_deg).sum(axis=1)
    return np.floor(lo) - 1.0, np.ceil(hi) + 1.0


def check_dh_matches_opw(dh: DhTable, params: OpwParams) -> None:
    """Raise ValueError unless the OPW parameters reproduce the D-H forward kinematics."""
    rng = np.random.default_rng(0)
    samples = [np.zeros(6)] + list(rng.uniform(-180.0, 180.0, (DH_CHECK_SAMPLES, 6)))
    worst, at = 0.0, None
    for q in samples:
        a = fk_dh(dh, q)[:3]
        b = np.array(opw_fk(params, q.tolist()))
        err = float(np.max(np.abs(a - b)))
        if err > worst:
            worst, at = err, q
    if worst > DH_CHECK_TOL:
        qs = " ".join(f"{v:.1f}" for v in at)
        raise ValueError(
            f"[dh] and [opw] disagree: forward kinematics differ by {worst:.3g} (mm or rotation) at q = [{qs}] deg"
        )
