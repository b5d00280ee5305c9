"""Which implementation runs the 500 Hz pair: the compiled kernel or the Python reference (issue 28 item 1).

The servo program's PID (thesis §4.1.5.1, :mod:`droid.subunits.reis.pid`) and the Reis plant
twin's exact zero-order-hold step (:mod:`droid.sim.reis.plant`) exist twice: the Python
reference and one compiled implementation, :mod:`droid._kernel` (``droid/_kernel.c``, a CPython
C extension built by pip at install; setup.py).  ``DROID_KERNEL`` chooses, read once at import:

* ``auto`` (the default) -- the compiled kernel when it is built and answers bit for bit, else
  the Python reference (:data:`UNAVAILABLE` says why): results are the same bits either way,
  only the speed differs, so droid-servo, droid-sim's arm device and every lockstep trial run
  the compiled code in any install scripts/venv.sh made, and a checkout whose extension was
  not built still runs;
* ``c`` -- the compiled kernel, or nothing: if it cannot be used (not built, or numpy's BLAS
  not reachable or not answering bit for bit) importing this module raises
  :class:`KernelUnavailable` -- an explicit request never falls back;
* ``python`` -- the Python reference, which stays the specification (tests, benches).

The compiled kernel gives the **same bits** as the reference: the same IEEE operations in the
same order (built without FMA contraction or fast-math), libm's ``sin`` as ``math.sin``, and the
two matrix-vector products of the plant's step through the very ``cblas_dgemv`` numpy's ``@``
calls (its bundled OpenBLAS, found here and checked against ``@`` on :data:`CHECK_SHAPES` before
use).  tests/reis/test_kernel.py compares the two per step on random inputs, bit for bit;
docs/benchmarks.md "Issue 28 item 1" has the trial logs compared and the speed.

The plant's rigid-drive substeps (``rigid_steps``: droid-sim's world, rigid lockstep cells) also
solve ``M(q) qdd = tau`` as ``np.linalg.solve`` does: through numpy's own LAPACK ``dgesv`` (its
bundled OpenBLAS, found here beside ``cblas_dgemv`` and checked against ``np.linalg.solve`` on
:data:`SOLVE_CHECKS` seeded systems).  Where it is not found or does not answer bit for bit,
:data:`GESV_UNAVAILABLE` says why and only those substeps stay in Python (:func:`rigid_ready`);
the rest of the kernel is used as before, ``DROID_KERNEL=c`` included.

The extension also holds a serial arm's rigid-body dynamics (``rb_*``): droid-sim's world uses
them in place of Pinocchio when this module chooses the compiled kernel
(:func:`droid.arm.rigid_body.world_backend`).  They agree with Pinocchio to rounding, not bit
for bit, so lockstep trials keep Pinocchio whatever ``DROID_KERNEL`` says.

And the seam tracker's nearest-segment search (``seam_nearest``, issue 44): a lockstep trial puts it
on its tracker once droid.experiments.seam_kernel has checked it against the numpy reference
(droid.tasks.seam.patch.nearest_segment) bit for bit, including the order in which numpy's einsum
adds a row on this CPU.
"""
from __future__ import annotations

import ctypes
import os
import sys

import numpy as np

KERNELS = ("auto", "c", "python")
#: the environment variable that chooses (read once, at import)
ENV = "DROID_KERNEL"
#: (m, n) of the products the bit check compares with numpy's ``@`` before the kernel is used
CHECK_SHAPES = ((24, 36), (24, 6))
#: cblas_dgemv's names in numpy's BLAS builds, with their integer width: (symbol, 64-bit ints)
_GEMV_SYMBOLS = (("scipy_cblas_dgemv64_", True), ("cblas_dgemv64_", True), ("scipy_cblas_dgemv", False),
                 ("cblas_dgemv", False))
#: LAPACK dgesv's names (Fortran interface) in numpy's builds, with their integer width
_GESV_SYMBOLS = (("scipy_dgesv_64_", True), ("dgesv_64_", True), ("scipy_dgesv_", False), ("dgesv_", False))
#: systems the solve check compares with ``np.linalg.solve`` before the rigid substeps use it
SOLVE_CHECKS = 60


class KernelUnavailable(ImportError):
    """``DROID_KERNEL=c`` and the compiled kernel cannot be used (the message says why)."""


def _blas_libraries() -> list[str]:
    """Shared libraries this process has mapped whose name says BLAS (numpy's, once imported)."""
    paths = []
    try:
        with open("/proc/self/maps") as f:
            for line in f:
                path = line.rsplit(" ", 1)[-1].strip()
                if "blas" in os.path.basename(path).lower() and ".so" in path and path not in paths:
                    paths.append(path)
    except OSError:  # pragma: no cover - not Linux
        pass
    return paths


def _find_symbol(symbols, what: str) -> tuple[int, bool, str]:
    """(address, 64-bit ints, where) of the first of ``symbols`` ((name, int64) pairs) in the
    BLAS/LAPACK libraries numpy has loaded; KernelUnavailable naming ``what`` otherwise."""
    for path in _blas_libraries():
        try:
            lib = ctypes.CDLL(path)  # already loaded: the same handle, the same code
        except OSError:  # pragma: no cover
            continue
        for name, int64 in symbols:
            fn = getattr(lib, name, None)
            if fn is not None:
                return ctypes.cast(fn, ctypes.c_void_p).value, int64, f"{os.path.basename(path)}:{name}"
    raise KernelUnavailable(f"numpy's {what} not found among the loaded libraries "
                            f"({', '.join(map(os.path.basename, _blas_libraries())) or 'none'})")


def _find_gemv() -> tuple[int, bool, str]:
    """(address, 64-bit ints, where) of the cblas_dgemv numpy's ``@`` calls."""
    np.dot(np.ones((2, 2)), np.ones(2))  # numpy's BLAS is loaded by now in any case
    return _find_symbol(_GEMV_SYMBOLS, "BLAS (cblas_dgemv)")


def _find_gesv() -> tuple[int, bool, str]:
    """(address, 64-bit ints, where) of numpy's LAPACK dgesv (the one ``np.linalg.solve`` calls)."""
    np.linalg.solve(np.eye(2), np.ones(2))  # numpy's LAPACK is loaded by now in any case
    return _find_symbol(_GESV_SYMBOLS, "LAPACK (dgesv)")


def _check_gesv(k) -> None:
    """The kernel's solve against ``np.linalg.solve``, bit for bit, on seeded systems: general
    ones (a transposed copy would show) and symmetric positive definite ones spanning the plant's
    mass matrices' conditioning (1 .. 1e8)."""
    rng = np.random.default_rng(40)
    for i in range(SOLVE_CHECKS):
        n = 6 if i % 3 else int(rng.integers(1, 9))
        g = rng.standard_normal((n, n)) * 10.0 ** rng.uniform(-3, 3, (n, n))
        a = g if i % 2 else g @ g.T + np.diag(10.0 ** rng.uniform(-2, 6, n))
        b = rng.standard_normal(n) * 10.0 ** rng.uniform(-3, 3, n)
        x = np.empty(n)
        if k.solve(np.ascontiguousarray(a), b, x) != 0 or x.tobytes() != np.linalg.solve(a, b).tobytes():
            raise KernelUnavailable(f"the kernel's {n}x{n} solve differs from np.linalg.solve (another LAPACK?)")


def _setup_gesv(k) -> tuple[str, str]:
    """(where, "") with numpy's dgesv set in ``k`` and checked, or ("", why not)."""
    if not hasattr(k, "set_gesv"):
        return "", "droid._kernel was built before rigid_steps (rebuild it)"
    try:
        addr, int64, where = _find_gesv()
        k.set_gesv(addr, int64)
        _check_gesv(k)
    except KernelUnavailable as exc:
        k.set_gesv(0, True)  # unset: rigid_steps refuses to run
        return "", str(exc)
    return where, ""


def _check(k) -> None:
    """The kernel's products against numpy's ``@``, bit for bit, on seeded inputs spanning
    twelve decades (what the plant's matrices hold: 1e-9 .. 1e3)."""
    rng = np.random.default_rng(28)
    for m, n in CHECK_SHAPES * 20:
        a = rng.standard_normal((m, n)) * 10.0 ** rng.uniform(-6, 6, (m, n))
        x = rng.standard_normal(n) * 10.0 ** rng.uniform(-6, 6, n)
        y = np.empty(m)
        k.matvec(a, x, y)
        if y.tobytes() != (a @ x).tobytes():
            raise KernelUnavailable(f"the kernel's {m}x{n} product differs from numpy's @ (another BLAS?)")


def _load():
    try:
        from droid import _kernel
    except ImportError as e:
        raise KernelUnavailable(f"{ENV}=c but droid._kernel is not built ({e}); reinstall with "
                                "`pip install -e .` (needs gcc and Python's headers: scripts/venv.sh)") from e
    addr, int64, where = _find_gemv()
    _kernel.set_gemv(addr, int64)
    _check(_kernel)
    global GESV, GESV_UNAVAILABLE
    GESV, GESV_UNAVAILABLE = _setup_gesv(_kernel)
    return _kernel, where


def _choose():
    name = os.environ.get(ENV, "auto").strip().lower() or "auto"
    if name not in KERNELS:
        raise KernelUnavailable(f"{ENV}={name!r}: known kernels are {', '.join(KERNELS)}")
    if name == "python":
        return "python", None, None, ""
    try:
        k, where = _load()
    except KernelUnavailable as exc:
        if name == "c":
            raise
        return "python", None, None, str(exc)  # auto: the reference, the same bits
    return "c", k, where, ""


#: where numpy's dgesv was found for the rigid substeps, or ""; GESV_UNAVAILABLE: why not ("" if it was,
#: or if the compiled kernel was not loaded)
GESV, GESV_UNAVAILABLE = "", ""
#: "python" or "c": the implementation in use in this process; UNAVAILABLE: why ``auto`` chose
#: the reference ("" when it did not, or was not asked to)
NAME, _K, GEMV, UNAVAILABLE = _choose()


def compiled():
    """The compiled module (:mod:`droid._kernel`) when ``DROID_KERNEL=c``, else None."""
    return _K


def describe() -> str:
    """One line: which kernel runs (for logs and benches)."""
    return (f"kernel {NAME}" + (f" ({_K.__file__}, BLAS {GEMV}" + (f", LAPACK {GESV})" if GESV else
                                 f"; the rigid substeps in Python: {GESV_UNAVAILABLE})") if _K is not None else "")
            + (f" (the compiled one is not usable: {UNAVAILABLE})" if UNAVAILABLE else ""))


def rigid_ready(k) -> bool:
    """Whether the compiled module ``k`` can take the plant's rigid-drive substeps (``rigid_steps``
    built and numpy's dgesv set and checked: :data:`GESV`)."""
    return k is not None and hasattr(k, "rigid_steps") and bool(GESV)


def load_compiled():
    """The compiled module, set up and checked, whatever ``DROID_KERNEL`` says (tests, benches)."""
    return _K if _K is not None else _load()[0]


if __name__ == "__main__":  # pragma: no cover
    print(describe(), file=sys.stdout)
