"""Unicycle with an acceleration input: the extension guide's example plant (docs/extending.md)."""

from __future__ import annotations

from dataclasses import dataclass

import casadi as ca

from mpclab.plants.base import Plant, register_plant


@dataclass
class UnicycleParams:
    drag: float = 0.0  # linear drag [1/s]: v' = a - drag v


@register_plant("unicycle")
class Unicycle(Plant):
    """``x = (px, py, theta, v)``, ``u = (a, omega)``: speed is a state, turn rate an input."""

    states = ("px", "py", "theta", "v")
    inputs = ("a", "omega")
    Params = UnicycleParams
    plot_states = ("v",)
    units = {"px": "m", "py": "m", "theta": "rad", "v": "m/s", "a": "m/s²", "omega": "rad/s"}

    def rhs(self, x: ca.SX, u: ca.SX) -> ca.SX:
        _, _, theta, v = ca.vertsplit(x)
        a, omega = ca.vertsplit(u)
        return ca.vertcat(
            v * ca.cos(theta), v * ca.sin(theta), omega, a - self.params.drag * v
        )
