"""Six-channel discrete PID with output limits and anti-windup (thesis §4.1.5.1).

Per servo tick, with e = target - position [counts]::

    I  <- clip(I + ki*e, +-integral_limit)            (not when it would deepen saturation)
    u   = kp*e + I + kd*(e - e_prev)                    [DAC counts]
    out = clip(u, dac_min, dac_max)

The thesis limits servo_cmd to its maximum and minimum "to avoid the integral
error accumulation"; here the integral is frozen while the output is saturated
in the direction of the error (conditional integration) and is also bounded by
``integral_limit``.  Six joints in plain Python floats: at this size that is
several times faster than numpy, and the servo tick is the hot loop.

With the compiled kernel in use (droid.kernel) :meth:`Pid.step` and :meth:`Pid.step_rounded` run in the
compiled kernel (droid/_kernel.c ``pid_step``): the same operations in the same order, the same
bits -- droid-servo and every lockstep trial alike.
"""
from __future__ import annotations

import numpy as np

from droid import kernel as _kernel_switch


class Pid:
    """Six (or n) independent PID channels; gains per tick (see module docstring)."""

    def __init__(self, kp, ki, kd, integral_limit, out_min: float, out_max: float, *, kernel: str | None = None):
        """``kernel``: "c" or "python" overrides ``DROID_KERNEL`` (tests, benches)."""
        if kernel not in (None, "c", "python"):
            raise ValueError(f"kernel {kernel!r}: 'c', 'python' or None (DROID_KERNEL)")
        self._k = (_kernel_switch.compiled() if kernel is None else
                   _kernel_switch.load_compiled() if kernel == "c" else None)
        self.kp = [float(x) for x in kp]
        self.ki = [float(x) for x in ki]
        self.kd = [float(x) for x in kd]
        self.integral_limit = [float(x) for x in integral_limit]
        self.out_min = float(out_min)
        self.out_max = float(out_max)
        self._integral = [0.0] * len(self.kp)  # [DAC counts]
        self._prev_error: list[float] | None = None
        n = len(self.kp)
        if self._k is not None:  # the compiled kernel's layout: gains (5, n), state (2, n)
            if not (len(self.ki) == len(self.kd) == len(self.integral_limit) == n) or n < 2:
                raise ValueError(f"PID gains of unequal lengths or fewer than 2 channels ({n})")
            self._gains = np.array(self.kp + self.ki + self.kd + self.integral_limit
                                   + [self.out_min, self.out_max] + [0.0] * (n - 2))
            self._state = np.zeros(2 * n)  # the integrals [DAC counts], then the previous errors [counts]
            self._first = True
            self.step = self._step_compiled
            self.step_rounded = self._step_rounded_compiled

    @property
    def integral(self) -> np.ndarray:
        """Integral terms [DAC counts]."""
        if self._k is not None:
            return self._state[:len(self.kp)].copy()
        return np.array(self._integral)

    def reset(self) -> None:
        """Zero the integral and forget the previous error (no derivative kick)."""
        self._integral = [0.0] * len(self.kp)
        self._prev_error = None
        if self._k is not None:
            self._state[:] = 0.0
            self._first = True

    def _step_compiled(self, error_counts) -> list[float]:
        out = self._k.pid_step(self._gains, self._state, self._first, error_counts, False)
        self._first = False
        return out

    def _step_rounded_compiled(self, error_counts) -> tuple[int, ...]:
        out = self._k.pid_step(self._gains, self._state, self._first, error_counts, True)
        self._first = False
        return out

    def tail_compiled(self, target, previous, lo, hi, pos, fe_max, vel) -> tuple[int, ...] | None:
        """ServoCore's tick tail in the compiled kernel (``servo_tail``: clip ``target`` to
        ``lo``/``hi`` [counts] when given, ``vel`` = target - previous, the following-error check
        against ``fe_max``, then this PID, rounded): the DAC words, or None on a following error."""
        dac = self._k.servo_tail(target, previous, lo, hi, pos, fe_max, vel, self._gains, self._state, self._first)
        if dac is not None:
            self._first = False
        return dac

    def step_rounded(self, error_counts) -> tuple[int, ...]:
        """One tick, the outputs rounded half to even [DAC counts, int] (ServoCore.step's DACs)."""
        return tuple(map(round, self.step(error_counts)))

    def step(self, error_counts) -> list[float]:
        """One tick: errors [counts] -> limited outputs [DAC counts, float]."""
        e_now = [float(x) for x in error_counts]
        prev = self._prev_error if self._prev_error is not None else e_now
        self._prev_error = e_now
        lo, hi = self.out_min, self.out_max
        out = []
        append = out.append
        integral = self._integral
        for j, (e, ep, kp, ki, kd, lim, i0) in enumerate(zip(e_now, prev, self.kp, self.ki, self.kd,
                                                              self.integral_limit, integral)):
            pd = kp * e + kd * (e - ep)
            candidate = i0 + ki * e  # clipped to +-lim (comparisons: cheaper than min/max calls)
            if candidate > lim:
                candidate = lim
            elif candidate < -lim:
                candidate = -lim
            u = pd + candidate
            if not ((u > hi and e > 0.0) or (u < lo and e < 0.0)):  # conditional integration
                integral[j] = i0 = candidate
            u = pd + i0
            append(hi if u > hi else (lo if u < lo else u))
        return out
