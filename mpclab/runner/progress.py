"""Progress of one run: a live line on a terminal, and an estimate whenever a run looks long.

A run that looks long (its estimated wall time, if it runs to ``t_max``, is above
``long_after_s``) says so once in the log, with the time per simulated second and the
estimate, and then logs its progress every tenth of ``t_max``, also when nobody watches a
terminal (a sweep's job, a redirected run).
"""

from __future__ import annotations

import logging
import math
import sys
import time
from typing import TextIO

log = logging.getLogger("mpclab")


def clock(seconds: float) -> str:
    """``h:mm:ss`` of a duration (``?`` when not finite)."""
    if not math.isfinite(seconds):
        return "?"
    s = int(round(seconds))
    return f"{s // 3600}:{s % 3600 // 60:02d}:{s % 60:02d}"


class RunProgress:
    """``progress(t, t_max)`` after each step of :func:`mpclab.runner.loop.simulate`.

    Parameters
    ----------
    name
        The experiment's name, at the start of every line.
    live
        Redraw a one-line display on ``stream`` (a terminal) after every percent.
    long_after_s
        A run whose estimated wall time is above this is long: it is announced with its
        estimate and then logged every tenth of the way [s].
    settle_s
        Wall time after the first step before the first estimate [s]. The rate is measured
        from the end of the first step on: the first step includes building (and compiling)
        the controller, which says so itself.
    """

    def __init__(self, name: str, live: bool, long_after_s: float = 60.0,
                 settle_s: float = 2.0, stream: TextIO | None = None) -> None:
        self.name = name
        self.live = live
        self.long_after_s = long_after_s
        self.settle_s = settle_s
        self.stream = stream if stream is not None else sys.stderr
        self.long = False
        self._pct = -1
        self._tenth = 0
        self._start = time.perf_counter()
        self._first: tuple[float, float] | None = None  # (t, wall) after the first step

    def __call__(self, t: float, t_max: float) -> None:
        wall = time.perf_counter() - self._start
        if self._first is None and t > 0:
            self._first = (t, wall)
        t0, w0 = self._first or (0.0, 0.0)
        rate = (wall - w0) / (t - t0) if t > t0 else math.inf  # wall s per simulated s
        left = rate * (t_max - t)  # if it runs to t_max
        if (not self.long and self._first is not None and wall - w0 >= self.settle_s
                and wall + left > self.long_after_s):
            self.long = True
            log.warning(
                "%s: a long run: %.2f s of compute per simulated second so far; about %s "
                "in all if it runs to t_max = %g s (progress every 10 %%; Ctrl-C keeps the "
                "steps so far, status 'interrupted')", self.name, rate, clock(wall + left),
                t_max,
            )
        tenth = int(10 * t / t_max)
        if self.long and tenth > self._tenth and not self.live:
            self._tenth = tenth
            log.info("%s: t = %.1f of %g s | elapsed %s, at most %s left", self.name, t,
                     t_max, clock(wall), clock(left))
        pct = int(100 * t / t_max)
        if self.live and pct != self._pct:
            self._pct = pct
            self.stream.write(f"\r{self.name}: t = {t:6.2f} s of at most {t_max:.1f} s"
                              f" | elapsed {clock(wall)}, at most {clock(left)} left ")
            self.stream.flush()

    def done(self) -> None:
        if self.live:
            self.stream.write("\n")
