"""The compiled rigid-body dynamics (droid/_kernel.c ``rb_*``, RigidBody(backend="kernel")) against
Pinocchio, and droid-sim's world without Pinocchio.

The kernel runs Featherstone's RNEA and CRBA in its own operation order, so it agrees with
Pinocchio to rounding, not bit for bit.  Tolerances, as the norm of the difference relative to
the norm of Pinocchio's answer (vector 2-norm, matrix Frobenius norm), on a few hundred random
states per arm:

* RNEA (``nle``, ``gravity``, the full ``tau``), ``M``, joint 6's placement and Jacobian,
  ``wcp_mm``: :data:`RTOL` (1e-12; measured <= 2.1e-15, and 1.2e-14 for ``tau - g``, a
  difference of Pinocchio's two answers);
* ``M^-1`` and the forward dynamics (ABA): :data:`RTOL_SOLVE` times ``cond(M)`` (a solve loses
  up to ``cond(M)`` ulps; cond(M) is 37 .. 6.2e3 on these arms; measured <= 6.0e-13 for
  ``M^-1``, <= 2.4e-14 for ABA, i.e. <= 1.6e-16 cond(M)).

The kernel is built with the package (setup.py); these tests fail, not skip, when it is missing.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from droid import kernel
from droid.kinematics import load_robot
from droid.arm.rigid_body import BACKENDS, DhError, RigidBody, pack_model
from droid.sim.reis.plant import ReisPlant, ReisPlantParams
from droid.subunits.reis import vme_map as vm

ROOT = Path(__file__).resolve().parents[2]
#: every bundled robot file with [dynamics] and [dh]
ROBOTS = ("reis_v15", "reis_class_b", "fanuc_s400", "abb_irb2400")
RTOL = 1e-12
RTOL_SOLVE = 1e-14
N_STATES = 300
BASE_T_MM = np.array([[0.0, -1.0, 0.0, 1200.0], [0.6, 0.0, -0.8, -350.0], [0.8, 0.0, 0.6, 420.0], [0, 0, 0, 1.0]])


def _k():
    return kernel.load_compiled()  # raises KernelUnavailable (a failure) when not built


def _rel(a, b) -> float:
    return float(np.linalg.norm(np.asarray(a) - np.asarray(b)) / np.linalg.norm(b))


def _bodies(robot: str, case: str):
    m = load_robot(robot)
    dh = DhError(d_mm=(3.0, -2.0, 1.5, 0.5, -1.0, 2.5), a_mm=(1.0, 2.0, -3.0, 0.0, 1.0, -0.5),
                 alpha_deg=(0.3, -0.2, 0.1, 0.4, -0.3, 0.2)).apply(m.dh) if case == "dh_error" else m.dh
    base = BASE_T_MM if case == "base" else None
    return (RigidBody(dh, m.dynamics, base, backend="pinocchio"), RigidBody(dh, m.dynamics, base, backend="kernel"))


def _states(seed: int):
    """Random states: joint angles over two turns, speeds to 6 rad/s, accelerations and torques
    spanning decades (1e-3 .. 1e3)."""
    rng = np.random.default_rng(seed)
    for _ in range(N_STATES):
        q = rng.uniform(-2.0 * np.pi, 2.0 * np.pi, 6)
        qd = rng.uniform(-6.0, 6.0, 6) * (rng.random(6) < 0.9)
        qdd = rng.standard_normal(6) * 10.0 ** rng.uniform(-3, 3, 6)
        tau = rng.standard_normal(6) * 10.0 ** rng.uniform(-3, 3, 6)
        yield q, qd, qdd, tau


@pytest.mark.parametrize("case", ["file", "base", "dh_error"])
@pytest.mark.parametrize("robot", ROBOTS)
def test_kernel_dynamics_agree_with_pinocchio(robot, case):
    import pinocchio as pin

    P, K = _bodies(robot, case)
    k = _k()
    worst: dict[str, float] = {}

    def check(name, got, ref, tol):
        err = _rel(got, ref)
        worst[name] = max(worst.get(name, 0.0), err)
        assert err <= tol, f"{robot} ({case}) {name}: relative error {err:.2e} > {tol:.2e}"

    for q, qd, qdd, tau in _states(10 * ROBOTS.index(robot) + len(case)):
        M = P.mass(q)
        cond = np.linalg.cond(M)
        check("nle", K.nle(q, qd), P.nle(q, qd).copy(), RTOL)
        check("bias", K.bias(q, qd), P.bias(q, qd), RTOL)
        check("gravity", K.gravity(q), P.gravity(q), RTOL)
        full = np.empty(6)
        k.rb_rnea(K._buf, q, qd, qdd, True, full)
        check("rnea", full, pin.rnea(P.model, P.data, q, qd, qdd).copy(), RTOL)
        k.rb_rnea(K._buf, q, qd, qdd, False, full)  # without gravity: M qdd + C qd
        check("rnea_no_g", full, pin.rnea(P.model, P.data, q, qd, qdd) - P.gravity(q), RTOL)
        check("mass", K.mass(q), M, RTOL)
        check("minv", K.minv(q), P.minv(q), RTOL_SOLVE * cond)
        check("aba", K.aba(q, qd, tau), P.aba(q, qd, tau).copy(), RTOL_SOLVE * cond)
        q_deg = np.degrees(q)
        check("wcp_mm", K.wcp_mm(q_deg), P.wcp_mm(q_deg), RTOL)
        (Jk, Rk, ok), (Jp, Rp, op) = K.joint6_jacobian_world(q), P.joint6_jacobian_world(q)
        check("jacobian", Jk, Jp, RTOL)
        check("R6", Rk, Rp, RTOL)
        check("o6", ok, op, RTOL)
    print(f"{robot} ({case}): worst relative error " + ", ".join(f"{n} {e:.1e}" for n, e in worst.items()))


def test_kernel_matrices_are_symmetric_and_inverse():
    _, K = _bodies("reis_v15", "file")
    for q, _, _, _ in _states(3):
        M, Mi = K.mass(q), K.minv(q)
        assert np.array_equal(M, M.T) and np.array_equal(Mi, Mi.T)
        assert np.abs(M @ Mi - np.eye(6)).max() < 1e-12 * np.linalg.cond(M)


def test_forward_and_inverse_dynamics_are_each_others_inverse():
    """RNEA(q, qd, ABA(q, qd, tau)) = tau, within RTOL of the torques' scale (kernel only)."""
    _, K = _bodies("fanuc_s400", "base")
    k = _k()
    back = np.empty(6)
    for q, qd, _, tau in _states(4):
        k.rb_rnea(K._buf, q, qd, K.aba(q, qd, tau), True, back)
        assert np.linalg.norm(back - tau) <= RTOL * (np.linalg.norm(tau) + np.linalg.norm(K.nle(q, qd)))


def test_a_wrong_gravity_or_joint_axis_is_caught():
    """The comparison can fail: a model with gravity flipped, or a joint 3 placement changed,
    differs from Pinocchio far beyond the tolerance."""
    P, K = _bodies("reis_v15", "file")
    q = np.radians([10.0, -30.0, 40.0, 20.0, 50.0, -10.0])
    buf = K._buf.copy()
    buf[-1] = -buf[-1]
    g = np.empty(6)
    _k().rb_rnea(buf, q, None, None, True, g)
    assert _rel(g, P.gravity(q)) > 1.0
    buf = K._buf.copy()
    buf[25 * 2 + 9] += 0.01  # joint 3's origin 10 mm off
    _k().rb_rnea(buf, q, None, None, True, g)
    assert _rel(g, P.gravity(q)) > 1e-4


def test_bad_buffers_raise_clear_errors():
    k = _k()
    _, K = _bodies("reis_v15", "file")
    buf, q, out6, out66 = K._buf, np.zeros(6), np.empty(6), np.empty((6, 6))
    with pytest.raises(ValueError, match=r"model: 1216 bytes, need 8 \* \(25 n \+ 3\)"):
        k.rb_rnea(buf[:-1], q, None, None, True, out6)
    with pytest.raises(ValueError, match="model"):
        k.rb_crba(np.zeros(3), q, out66)  # no joint
    with pytest.raises(ValueError, match="model"):
        k.rb_crba(np.zeros(25 * 17 + 3), np.zeros(17), np.empty((17, 17)))  # too many joints
    with pytest.raises(ValueError, match="q: 40 bytes, need 48"):
        k.rb_crba(buf, np.zeros(5), out66)
    with pytest.raises(ValueError, match="qd: 56 bytes, need 48"):
        k.rb_rnea(buf, q, np.zeros(7), None, True, out6)
    with pytest.raises(ValueError, match="M: 280 bytes, need 288"):
        k.rb_crba(buf, q, np.empty(35))
    with pytest.raises(ValueError, match="J: 280 bytes, need 288"):
        k.rb_jacobian(buf, q, np.empty(35), np.empty((4, 4)))
    with pytest.raises(ValueError, match="oM"):
        k.rb_jacobian(buf, q, None, np.empty(12))
    with pytest.raises(ValueError, match="qdd"):
        k.rb_aba(buf, q, q, q, np.empty(5))
    with pytest.raises(TypeError, match="rb_aba takes 5 arguments"):
        k.rb_aba(buf, q, q, q)
    with pytest.raises(TypeError, match="rb_rnea takes 6 arguments"):
        k.rb_rnea()
    ro = np.empty(6)
    ro.flags.writeable = False
    with pytest.raises((ValueError, BufferError)):
        k.rb_rnea(buf, q, None, None, True, ro)
    with pytest.raises((ValueError, BufferError)):
        k.rb_rnea(buf, np.zeros(12)[::2], None, None, True, out6)  # not contiguous
    bad = buf.copy()
    bad[25 * 5 + 12:25 * 6] = 0.0  # link 6 without mass or inertia: M is singular
    with pytest.raises(ValueError, match="not positive definite"):
        k.rb_minv(bad, q, out66)
    with pytest.raises(ValueError, match="backend"):
        RigidBody(load_robot("reis_v15").dh, load_robot("reis_v15").dynamics, backend="numpy")
    assert BACKENDS == ("pinocchio", "kernel")


def test_packed_model_layout():
    m = load_robot("reis_v15")
    buf = pack_model(m.dh, m.dynamics)
    assert buf.shape == (25 * 6 + 3,) and buf.dtype == np.float64 and buf.flags.c_contiguous
    assert (_k().RB_PER_JOINT, _k().RB_MAXJ) == (25, 16)
    assert np.array_equal(buf[12::25][:6], np.asarray(m.dynamics.link_mass_kg, float))
    assert np.array_equal(buf[-3:], [0.0, 0.0, -m.dynamics.gravity_mps2])


def _drive(plant: ReisPlant, seconds: float, dt: float = 0.002) -> None:
    """Amplifiers on (both watchdogs kicked every 20 ms), a fixed DAC pattern (joint 1 .. 6)."""
    view = memoryview(plant.regs).cast("B")
    vm.store(view, vm.DAC_OFFSET, vm.DACS_FORMAT, 300, -250, 200, 150, -120, 100)
    for i in range(int(round(seconds / dt))):
        if i % 10 == 0:
            for j, off in enumerate(vm.WATCHDOG_OFFSETS):
                vm.store(view, off, vm.U16_FORMAT, (i // 10 + j) % 65536)
        plant.advance(dt)
    view.release()


@pytest.mark.parametrize("how", [dict(), dict(compliance=False), dict(integrator="substep")])
def test_the_plant_on_the_kernel_follows_the_plant_on_pinocchio(how):
    """One second of a driven arm: the two backends' plants end within 1e-9 deg and 1e-9 deg/s
    of each other (exact and substep integrators, compliant and rigid drives)."""
    params = ReisPlantParams(initial_joint_deg=(10.0, -20.0, 30.0, 0.0, 40.0, 0.0), **how)
    a, b = (ReisPlant(params, seed=3, rigid_body=r) for r in ("pinocchio", "kernel"))
    assert (a.body.backend, b.body.backend) == ("pinocchio", "kernel")
    _drive(a, 1.0)
    _drive(b, 1.0)
    assert a.amps_on and b.amps_on
    moved = np.abs(a.joint_deg - np.degrees(np.radians([10.0, -20.0, 30.0, 0.0, 40.0, 0.0]))).max()
    assert moved > 1.0  # the arm did move
    np.testing.assert_allclose(b.joint_deg, a.joint_deg, rtol=0, atol=1e-9)
    np.testing.assert_allclose(np.degrees(b._qd), np.degrees(a._qd), rtol=0, atol=1e-9)
    np.testing.assert_allclose(b.wcp_true(), a.wcp_true(), rtol=0, atol=1e-9)


def test_lockstep_plants_keep_pinocchio():
    """The default (lockstep trials, the published tables) is Pinocchio."""
    from droid.sim.reis.lockstep import make_reis_cell

    assert ReisPlant(ReisPlantParams(), seed=1).body.backend == "pinocchio"
    assert make_reis_cell(seed=1).plant.body.backend == "pinocchio"


WORLD_SCRIPT = textwrap.dedent("""
    import json, sys
    from droid.brain.cell.cellfile import load_cell
    from droid.brain.cell.registry import validate_cell
    from droid.sim.world import build_world
    cell = load_cell(sys.argv[1])
    validate_cell(cell)
    world = build_world(cell)
    try:
        for _ in range(50):
            world.advance(0.001)
        gmf1 = world.devices["gmf1_karel"].controller.arm
        out = {"pinocchio": sorted(m for m in sys.modules if m.split(".")[0] in ("pinocchio", "coal", "eigenpy")),
               "arm1": world.devices["arm1"].plant.body.backend, "gmf1": gmf1.body.backend if gmf1 else None}
    finally:
        world.close()
    print(json.dumps(out))
""")


def _world_in_subprocess(tmp_path, cell_name, env_kernel: str) -> dict:
    from droid.brain.cell.cellfile import builtin_cell_path

    text = builtin_cell_path().read_text().replace('name = "sim"', f'name = "{cell_name}"\nrun_dir = "{tmp_path}/run"', 1)
    assert f'name = "{cell_name}"' in text
    (tmp_path / "cell.toml").write_text(text)
    env = dict(os.environ, PYTHONPATH=str(ROOT), DROID_KERNEL=env_kernel)
    r = subprocess.run([sys.executable, "-c", WORLD_SCRIPT, str(tmp_path / "cell.toml")], env=env, cwd=str(ROOT),
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr[-3000:]
    return json.loads(r.stdout.strip().splitlines()[-1])


def test_droid_sims_world_never_imports_pinocchio(tmp_path, cell_name):
    """The default cell's world, built as droid-sim builds it, in a fresh process: the Reis plant
    and the GMF1's arm twin on the compiled kernel, and no pinocchio, coal or eigenpy module."""
    out = _world_in_subprocess(tmp_path, cell_name, "auto")
    assert out == {"pinocchio": [], "arm1": "kernel", "gmf1": "kernel"}


def test_droid_sims_world_falls_back_to_pinocchio_without_the_kernel(tmp_path, cell_name):
    out = _world_in_subprocess(tmp_path, cell_name, "python")
    assert "pinocchio" in out["pinocchio"] and (out["arm1"], out["gmf1"]) == ("pinocchio", "pinocchio")


@pytest.mark.parametrize("robot", ROBOTS)
def test_nle_fn_is_nle_bit_for_bit(robot):
    """``RigidBody.nle_fn`` -- what the plant's one-call exact step calls every 2 ms (issue 44) --
    gives ``nle``'s bits on both backends (Pinocchio's: its own call on the same model and data,
    without the Python frame), on random states; Pinocchio's answer depends on the state (a
    constant would fail)."""
    rng = np.random.default_rng(7)
    for body in _bodies(robot, "dh_error"):
        seen = set()
        for _ in range(50):
            q, qd = rng.uniform(-3.0, 3.0, 6), rng.uniform(-2.0, 2.0, 6)
            want = body.nle(q, qd).copy()
            got = np.asarray(body.nle_fn(q, qd)).copy()
            assert got.tobytes() == want.tobytes()
            seen.add(got.tobytes())
        assert len(seen) == 50
