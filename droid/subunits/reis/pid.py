"""Six-channel discrete PID with output limits and anti-windup (thesis §4.1.5.1).

Per servo tick, with e = target - position [counts]::

    I  <- clip(I + ki*e, +-integral_limit)            (not when it would deepen saturation)
    u   = kp*e + I + kd*(e - e_prev)                    [DAC counts]
    out = clip(u, dac_min, dac_max)

The thesis limits servo_cmd to its maximum and minimum "to avoid the integral
error accumulation"; here the integral is frozen while the output is saturated
in the direction of the error (conditional integration) and is also bounded by
``integral_limit``.
"""
from __future__ import annotations

import numpy as np


class Pid:
    """Vectorized PID over six joints; gains per tick (see module docstring)."""

    def __init__(self, kp, ki, kd, integral_limit, out_min: float, out_max: float):
        self.kp = np.asarray(kp, float)
        self.ki = np.asarray(ki, float)
        self.kd = np.asarray(kd, float)
        self.integral_limit = np.asarray(integral_limit, float)
        self.out_min = float(out_min)
        self.out_max = float(out_max)
        self.integral = np.zeros_like(self.kp)  # [DAC counts]
        self._prev_error: np.ndarray | None = None

    def reset(self) -> None:
        """Zero the integral and forget the previous error (no derivative kick)."""
        self.integral = np.zeros_like(self.kp)
        self._prev_error = None

    def step(self, error_counts: np.ndarray) -> np.ndarray:
        """One tick: ``error_counts`` (6,) -> limited output [DAC counts, float] (6,)."""
        e = np.asarray(error_counts, float)
        d = np.zeros_like(e) if self._prev_error is None else e - self._prev_error
        self._prev_error = e
        pd = self.kp * e + self.kd * d
        candidate = np.clip(self.integral + self.ki * e, -self.integral_limit, self.integral_limit)
        u = pd + candidate
        winding = ((u > self.out_max) & (e > 0)) | ((u < self.out_min) & (e < 0))
        self.integral = np.where(winding, self.integral, candidate)
        return np.clip(pd + self.integral, self.out_min, self.out_max)
