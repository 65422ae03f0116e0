"""Kinematic car (Study A): rear-axle bicycle with speed and steering angle as states."""

from __future__ import annotations

from dataclasses import dataclass

import casadi as ca

from mpclab.plants.base import Plant, register_plant


@dataclass
class KinematicCarParams:
    l: float = 1.0  # wheelbase [m]


@register_plant("kinematic_car")
class KinematicCar(Plant):
    """``x = (px, py, theta, v, phi)``, ``u = (a, phi_dot)``.

    ``theta' = v tan(phi) / l`` (the study's equation writes ``tan(theta)``: a typo).
    """

    states = ("px", "py", "theta", "v", "phi")
    inputs = ("a", "phi_dot")
    Params = KinematicCarParams
    plot_states = ("v", "phi")
    units = {"px": "m", "py": "m", "theta": "rad", "v": "m/s", "phi": "rad", "a": "m/s²",
             "phi_dot": "rad/s"}

    def rhs(self, x: ca.SX, u: ca.SX) -> ca.SX:
        _, _, theta, v, phi = ca.vertsplit(x)
        a, phi_dot = ca.vertsplit(u)
        return ca.vertcat(
            v * ca.cos(theta),
            v * ca.sin(theta),
            v * ca.tan(phi) / self.params.l,
            a,
            phi_dot,
        )
