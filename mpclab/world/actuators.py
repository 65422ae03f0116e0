"""The motors between the controller's command and the plant (``sim.actuator``).

Off by default: the plant sees the command itself, held over the period. With a **time
constant** ``T`` (``time_constant_s``) each input follows its command as a first-order lag,
``u' = (c - u) / T``; with a **rate limit** ``R`` (``rate_limit``, in the input's unit per
second: rad/s² for the Zumo's wheel speeds) it moves towards its command at most ``R`` per
second; with both, ``u' = clip((c - u) / T, -R, R)``. The output starts at zero (the robot
at rest) and is continuous in time.

The response to a command held over a piece of the period is exact (a ramp, then an
exponential, per input). The plant integrates it as short pieces of constant input: each
the exact mean of the output over the piece (so a wheel's travel, what an encoder counts, is
exact at every piece's end), none longer than ``min(T / 4, dt / 10)``, split where a ramp
ends; a rate limit alone holds the command, in one piece, once it is reached.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from mpclab.core.errors import number
from mpclab.plants.base import FloatArray

#: the longest piece of constant input, as fractions of the time constant and the period
_PER_TIME_CONSTANT = 4
_PER_PERIOD = 10

Pieces = list[tuple[FloatArray, float]]


class Actuator:
    """The actuators' response (see the module docstring).

    Parameters
    ----------
    time_constant_s
        First-order lag of every input [s]; ``None``: none.
    rate_limit
        Largest rate of change of every input [input unit / s]; ``None``: none.
    """

    def __init__(self, time_constant_s: float | None = None,
                 rate_limit: float | None = None) -> None:
        self.time_constant_s = (None if time_constant_s is None else
                                number(time_constant_s, "sim.actuator.time_constant_s", above=0))
        self.rate_limit = (None if rate_limit is None else
                           number(rate_limit, "sim.actuator.rate_limit", above=0))
        #: whether the plant sees anything but the command
        self.active = self.time_constant_s is not None or self.rate_limit is not None
        self.output = np.zeros(0)

    def reset(self, nu: int) -> None:
        """At rest: every output zero."""
        self.output = np.zeros(nu)

    def respond(self, commands: Sequence[tuple[FloatArray, float]], dt: float
                ) -> tuple[Pieces, FloatArray]:
        """The output's pieces of constant input ``[(input, duration)]`` under the commands
        ``[(command, duration)]`` held one after the other from the present output, and the
        output at their end. The present output is left as it is (:meth:`commit` moves it)."""
        if not self.active:
            return [(np.asarray(c, dtype=float), d) for c, d in commands], self.output
        out, pieces = self.output.copy(), []
        for command, duration in commands:
            if duration <= 0:
                continue
            more, out = self._hold(out, np.asarray(command, dtype=float), duration, dt)
            pieces += more
        return pieces, out

    def commit(self, output: FloatArray) -> None:
        self.output = np.asarray(output, dtype=float).copy()

    def describe(self) -> dict[str, float | None]:
        return {"time_constant_s": self.time_constant_s, "rate_limit": self.rate_limit}

    # ------------------------------------------------------------------ the response

    def _hold(self, u0: FloatArray, c: FloatArray, duration: float, dt: float
              ) -> tuple[Pieces, FloatArray]:
        """Pieces over ``[0, duration]`` from output ``u0`` under the command ``c``."""
        lag = self.time_constant_s or 0.0
        rate = self.rate_limit or math.inf
        # each input ramps at the rate limit until it is within rate * T of its command
        ramp_end = (np.maximum(0.0, (np.abs(c - u0) - rate * lag) / rate)
                    if math.isfinite(rate) else np.zeros_like(u0))
        cuts = sorted({0.0, duration, *(float(t) for t in ramp_end if 0 < t < duration)})
        longest = dt / _PER_PERIOD
        if lag > 0:
            longest = min(longest, lag / _PER_TIME_CONSTANT)
        grid = [0.0]
        for a, b in zip(cuts[:-1], cuts[1:], strict=True):
            settled = lag == 0 and a >= ramp_end.max()  # a rate limit alone: reached
            n = 1 if settled else max(1, math.ceil((b - a) / longest - 1e-9))
            grid += list(np.linspace(a, b, n + 1)[1:])
        grid[-1] = duration
        travel = [self._travel(u0, c, t, ramp_end, lag, rate) for t in grid]
        pieces = [((travel[i + 1] - travel[i]) / (grid[i + 1] - grid[i]),
                   grid[i + 1] - grid[i]) for i in range(len(grid) - 1)]
        return pieces, self._output(u0, c, duration, ramp_end, lag, rate)

    @staticmethod
    def _output(u0: FloatArray, c: FloatArray, t: float, ramp_end: FloatArray, lag: float,
                rate: float) -> FloatArray:
        """The output at time ``t`` of holding ``c`` from ``u0``."""
        sign = np.sign(c - u0)
        ramp = np.minimum(t, ramp_end)
        u_s = u0 + sign * (rate * ramp if math.isfinite(rate) else 0.0)
        if lag == 0:
            return np.where(t >= ramp_end, c, u_s)
        return c - (c - u_s) * np.exp(-np.maximum(t - ramp_end, 0.0) / lag)

    @staticmethod
    def _travel(u0: FloatArray, c: FloatArray, t: float, ramp_end: FloatArray, lag: float,
                rate: float) -> FloatArray:
        """The integral of the output over ``[0, t]`` (a wheel's angle travelled)."""
        sign = np.sign(c - u0)
        ramp = np.minimum(t, ramp_end)
        slope = sign * rate if math.isfinite(rate) else np.zeros_like(u0)
        along = u0 * ramp + slope * ramp**2 / 2  # the ramp phase
        u_s = u0 + slope * ramp
        after = np.maximum(t - ramp_end, 0.0)
        if lag == 0:
            return along + c * after
        return along + c * after - (c - u_s) * lag * (1 - np.exp(-after / lag))
