"""The grid of operating points a scheduled MPC switches or interpolates between.

The grid is the product of one list of values per scheduling state (the study: ``theta`` in
``{0, pi/2, pi, -pi/2}`` x ``V`` in ``{1, 2}``). The plant's heading is periodic (2 pi): its
values are compared on the circle, and a state's heading is matched to the nearest copy
``theta_i + 2 pi k`` of a grid heading (``k`` is returned so the caller can shift the model).
"""

from __future__ import annotations

import bisect
import itertools
import math
from collections.abc import Mapping, Sequence

import numpy as np

from mpclab.core.errors import ConfigError

TWO_PI = 2.0 * math.pi


class _Axis:
    """One scheduling state: its index in the state vector and its sorted grid values."""

    def __init__(self, label: str, index: int, values: Sequence[float], periodic: bool) -> None:
        vals = [float(v) for v in values]
        if not vals:
            raise ConfigError(f"controller.schedule.operating_points.{label} is empty")
        key = [v % TWO_PI for v in vals] if periodic else vals
        if len(set(np.round(key, 12))) != len(key):
            raise ConfigError(
                f"controller.schedule.operating_points.{label} has repeated values"
                f"{' (modulo 2 pi)' if periodic else ''}: {vals}"
            )
        self.label, self.index, self.periodic = label, index, periodic
        #: values in config order (the op index follows this order)
        self.values = vals
        order = sorted(range(len(vals)), key=lambda i: key[i])
        self._order = order                      # config indices sorted by value
        self._sorted = [key[i] for i in order]   # ascending (in [0, 2 pi) if periodic)

    def nearest(self, v: float) -> tuple[int, float]:
        """``(config index, distance)`` of the grid value nearest to ``v``."""
        best, dist = 0, math.inf
        if self.periodic:
            for i, g in enumerate(self.values):
                d = abs((v - g + math.pi) % TWO_PI - math.pi)
                if d < dist:
                    best, dist = i, d
        else:
            for i, g in enumerate(self.values):
                d = abs(v - g)
                if d < dist:
                    best, dist = i, d
        return best, dist

    def cells(self) -> tuple[list[float], list[int]]:
        """Midpoints between neighbouring values and the config index nearest in each cell.

        ``indices[bisect(cuts, v)]`` is the nearest value's index (``v`` taken modulo 2 pi
        when periodic: the cells then wrap around through 0).
        """
        s, order = self._sorted, self._order
        mids = [(a + b) / 2 for a, b in zip(s[:-1], s[1:], strict=True)]
        if not self.periodic:
            return mids, list(order)
        wrap = (s[-1] + s[0] + TWO_PI) / 2  # midpoint across 2 pi
        return [wrap - TWO_PI, *mids, wrap], [order[-1], *order, order[0]]

    def distance(self, v: float, i: int) -> float:
        d = v - self.values[i]
        return abs(_wrap(d)) if self.periodic else abs(d)

    def bracket(self, v: float) -> list[tuple[int, float]]:
        """Config indices and linear-interpolation weights of the neighbours of ``v``.

        Non-periodic: clamped at the ends (weight 1 on the end point outside the grid).
        Periodic: the two headings either side of ``v`` on the circle.
        """
        s, n = self._sorted, len(self._sorted)
        if n == 1:
            return [(self._order[0], 1.0)]
        if self.periodic:
            w = v % TWO_PI
            j = int(np.searchsorted(s, w, side="right")) - 1   # -1: below the first value
            lo_val = s[j] if j >= 0 else s[-1] - TWO_PI
            hi_j = (j + 1) % n
            hi_val = s[hi_j] if j + 1 < n else s[0] + TWO_PI
            lo, hi = self._order[j % n], self._order[hi_j]
        else:
            if v <= s[0]:
                return [(self._order[0], 1.0)]
            if v >= s[-1]:
                return [(self._order[-1], 1.0)]
            j = int(np.searchsorted(s, v, side="right")) - 1
            lo_val, hi_val, lo, hi = s[j], s[j + 1], self._order[j], self._order[j + 1]
            w = v
        a = (w - lo_val) / (hi_val - lo_val)
        return [(lo, 1.0 - a), (hi, a)]


class OperatingGrid:
    """Product grid of operating points over some state labels.

    Parameters
    ----------
    points
        ``{state label: values}``; the op index runs over the product in the given order
        (last label fastest).
    state_index
        Maps a label to its index in the state vector (raises ValueError if unknown).
    periodic
        The label whose values are angles (compared modulo 2 pi), or None.
    hysteresis
        ``{label: margin}``: in :meth:`switched`, keep the active value of that label until
        another grid value is nearer by more than the margin.
    """

    def __init__(
        self, points: Mapping[str, Sequence[float]], state_index, periodic: str | None,
        hysteresis: Mapping[str, float] | None = None,
    ) -> None:
        if not points:
            raise ConfigError("controller.schedule.operating_points is empty: give "
                              "{state label: values}")
        self.axes: list[_Axis] = []
        for label, values in points.items():
            try:
                idx = state_index(label)
            except ValueError as exc:
                raise ConfigError(f"controller.schedule.operating_points: {exc}") from None
            self.axes.append(_Axis(label, idx, values, label == periodic))
        labels = [a.label for a in self.axes]
        hysteresis = dict(hysteresis or {})
        for label, h in hysteresis.items():
            if label not in labels:
                raise ConfigError(
                    f"controller.schedule.hysteresis: {label!r} is not a scheduling state; "
                    f"valid: {', '.join(labels)}"
                )
            if float(h) < 0:
                raise ConfigError(f"controller.schedule.hysteresis.{label} must be >= 0, got {h}")
        self.hysteresis = [float(hysteresis.get(a.label, 0.0)) for a in self.axes]
        self.shape = tuple(len(a.values) for a in self.axes)
        self._strides = [int(np.prod(self.shape[i + 1 :])) for i in range(len(self.shape))]
        #: per axis: the midpoints between neighbouring values and the op offset of each cell
        self._cuts = []
        for a, stride in zip(self.axes, self._strides, strict=True):
            cuts, cells = a.cells()
            self._cuts.append((a.index, a.periodic, cuts, [stride * i for i in cells]))
        #: periodic axis position and the state index of the heading (None: no periodic axis)
        self.periodic_axis = next((i for i, a in enumerate(self.axes) if a.periodic), None)

    @property
    def cell_table(self) -> list[tuple[int, bool, list[float], list[int]]]:
        """Per axis ``(state index, periodic, cuts, op offsets)``: :meth:`nearest`'s data."""
        return list(self._cuts)

    @property
    def labels(self) -> list[str]:
        return [a.label for a in self.axes]

    def __len__(self) -> int:
        return int(np.prod(self.shape))

    def points(self) -> list[dict[str, float]]:
        """Every operating point as ``{label: value}``, in op-index order."""
        return [
            {a.label: a.values[i] for a, i in zip(self.axes, idx, strict=True)}
            for idx in itertools.product(*(range(n) for n in self.shape))
        ]

    def flat(self, idx: Sequence[int]) -> int:
        return sum(i * s for i, s in zip(idx, self._strides, strict=True))

    def unflat(self, op: int) -> list[int]:
        return [(op // s) % n for s, n in zip(self._strides, self.shape, strict=True)]

    def heading(self, op: int) -> float | None:
        """The periodic (heading) value of operating point ``op``, or None."""
        p = self.periodic_axis
        return None if p is None else self.axes[p].values[self.unflat(op)[p]]

    def wraps(self, x: Sequence[float], op: int) -> int:
        """``k`` such that the heading of ``x`` is nearest to ``theta_op + 2 pi k`` (0 if none)."""
        p = self.periodic_axis
        if p is None:
            return 0
        ax = self.axes[p]
        return round((x[ax.index] - ax.values[self.unflat(op)[p]]) / TWO_PI)

    def nearest(self, x: Sequence[float]) -> int:
        """The op index nearest to ``x`` (nearest value per scheduling state)."""
        op = 0
        for index, periodic, cuts, ops in self._cuts:  # bisection in C: called every step
            v = x[index] % TWO_PI if periodic else x[index]
            op += ops[bisect.bisect(cuts, v)]
        return op

    def switched(self, x: Sequence[float], active: int | None) -> int:
        """Nearest op, but keep each active value while within its hysteresis margin."""
        if active is None or not any(self.hysteresis):
            return self.nearest(x)
        cur = self.unflat(active)
        idx = []
        for a, c, h in zip(self.axes, cur, self.hysteresis, strict=True):
            v = float(x[a.index])
            i, d = a.nearest(v)
            idx.append(c if a.distance(v, c) <= d + h else i)
        return self.flat(idx)

    def weights(self, x: Sequence[float]) -> list[tuple[int, float]]:
        """Multilinear interpolation: ``[(op index, weight)]`` with weights summing to 1."""
        out: list[tuple[list[int], float]] = [([], 1.0)]
        for a in self.axes:
            br = a.bracket(float(x[a.index]))
            out = [(idx + [i], w * wi) for idx, w in out for i, wi in br if w * wi > 0.0]
        return [(self.flat(idx), w) for idx, w in out]


def _wrap(a: float) -> float:
    """Angle in ``[-pi, pi)``."""
    return (a + math.pi) % TWO_PI - math.pi
