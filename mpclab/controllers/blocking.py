"""Move blocking: the control horizon, one definition for every backend that solves an OCP.

``controller.control_horizon`` says which inputs of the horizon are free:

* ``null``: every move ``u_0 .. u_{T-1}`` is free;
* an integer ``Nc`` in ``1..T``: ``u_0 .. u_{Nc-1}`` are free and the last is held to the end
  of the horizon (MATLAB's ``ControlHorizon``);
* a list of block lengths ``[m_1, m_2, ...]`` (MATLAB's blocking moves): one free move per
  block, held within it; a list that sums to less than ``T`` has its last block extended,
  one that sums to more is cut at ``T``.

The plan's inputs ``U (T, nu)`` are ``U = T V`` with ``V (M, nu)`` the free moves and ``T``
the 0/1 blocking matrix (:meth:`Blocking.matrix`): a backend substitutes it, so that its
decision vector holds ``M nu`` inputs, not ``T nu``. Stage costs and constraints still apply
at every step, on the held input; a term on input changes sees zero change within a block,
so it counts only at block starts. A warm start takes the previous plan's inputs (expanded
to ``T`` steps), shifts them by one step and re-blocks them (:meth:`Blocking.shift`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from mpclab.core.errors import ConfigError

FloatArray = npt.NDArray[np.float64]

#: what ``controller.control_horizon`` takes (a constructor's annotation)
ControlHorizon = int | Sequence[int] | None

_KEY = "controller.control_horizon"


@dataclass(frozen=True)
class Blocking:
    """Blocks of a horizon: ``blocks[j]`` steps share the free move ``j``.

    Attributes
    ----------
    horizon
        ``T``, the prediction steps.
    blocks
        The block lengths, positive and summing to ``T``; ``len(blocks)`` is ``M``.
    """

    horizon: int
    blocks: tuple[int, ...]

    @classmethod
    def of(cls, value: Any, horizon: int, key: str = _KEY) -> Blocking:
        """The blocking that ``controller.control_horizon = value`` gives over ``horizon``
        steps (module docstring); a bad value is a :class:`ConfigError` naming ``key``."""
        T = int(horizon)
        valid = (f"valid: null (every move free), an integer in 1..{T} (the first moves free, "
                 "the last held to the end) or a list of positive block lengths such as "
                 "[1, 2, 7]")
        if value is None:
            return cls(T, (1,) * T)
        if _integer(value):
            if not 1 <= value <= T:
                raise ConfigError(f"{key} must be in 1..{T} (the horizon), got {value}; {valid}")
            return cls(T, (1,) * (value - 1) + (T - value + 1,))
        if isinstance(value, Sequence) and not isinstance(value, str):
            lengths = list(value)
            if lengths and all(_integer(m) and m >= 1 for m in lengths):
                return cls(T, _fit(lengths, T))
        raise ConfigError(f"{key}: got {_shown(value)}; {valid}")

    @property
    def n_moves(self) -> int:
        """``M``, the free moves."""
        return len(self.blocks)

    @property
    def free(self) -> bool:
        """Whether every move is free (no blocking)."""
        return self.n_moves == self.horizon

    @property
    def starts(self) -> tuple[int, ...]:
        """The step at which each block starts."""
        return tuple(int(s) for s in np.cumsum((0, *self.blocks[:-1])))

    @property
    def move_of(self) -> np.ndarray:
        """``(T,)``: the free move each step applies."""
        return np.repeat(np.arange(self.n_moves), self.blocks)

    def matrix(self, nu: int = 1) -> FloatArray:
        """``T (T nu, M nu)``: stacked moves ``V`` to stacked inputs ``U = T V`` (step-major,
        each block of ``nu`` rows an identity)."""
        S = np.zeros((self.horizon, self.n_moves))
        S[np.arange(self.horizon), self.move_of] = 1.0
        return np.kron(S, np.eye(int(nu)))

    def expand(self, V: FloatArray) -> FloatArray:
        """The inputs ``(T, nu)`` of the moves ``V (M, nu)``."""
        if self.free:
            return np.array(V, dtype=float)
        return np.asarray(V, dtype=float)[self.move_of]

    def reblock(self, U: FloatArray) -> FloatArray:
        """The moves ``(M, nu)`` nearest to the inputs ``U (T, nu)`` in least squares: each
        block's mean (``U`` held within the blocks gives its moves back)."""
        if self.free:
            return np.array(U, dtype=float)
        U = np.asarray(U, dtype=float)
        sums = np.add.reduceat(U, np.asarray(self.starts), axis=0)
        return sums / np.asarray(self.blocks, dtype=float)[:, None]

    def shift(self, U: FloatArray) -> FloatArray:
        """The moves of the inputs ``U (T, nu)`` one step later: dropped the first, the last
        repeated, re-blocked (a warm start)."""
        U = np.asarray(U, dtype=float)
        return self.reblock(np.concatenate([U[1:], U[-1:]], axis=0))

    def summary(self) -> dict[str, Any]:
        """What a run's summary records: the free moves and the block lengths."""
        return {"control_horizon": self.n_moves, "blocks": list(self.blocks)}


def _integer(value: Any) -> bool:
    """Whether ``value`` is an integer (not a bool, not a float)."""
    return isinstance(value, (int, np.integer)) and not isinstance(value, bool)


def _fit(lengths: list[int], T: int) -> tuple[int, ...]:
    """Block lengths padded (the last extended) or cut to sum to ``T``."""
    out: list[int] = []
    left = T
    for m in lengths:
        if left == 0:
            break
        out.append(min(int(m), left))
        left -= out[-1]
    if left:
        out[-1] += left
    return tuple(out)


def _shown(value: Any) -> str:
    """``value`` as the user wrote it (a list config as a list)."""
    if isinstance(value, Sequence) and not isinstance(value, str):
        return str(list(value))
    return repr(value)
