"""Zumo two-wheeled robot (Study B): differential drive, wheel angular speeds as inputs."""

from __future__ import annotations

from dataclasses import dataclass

import casadi as ca

from mpclab.plants.base import Plant, register_plant


@dataclass
class ZumoParams:
    r: float = 0.02  # wheel radius [m] (ours: the study does not give it)
    d: float = 0.05  # half track, centre to wheel [m] (turning radius 5 cm)


@register_plant("zumo")
class Zumo(Plant):
    """``x = (x, y, theta)``, ``u = (u1, u2)`` = left, right wheel angular speed [rad/s].

    ``V = r (u1 + u2) / 2``, ``omega = r (u2 - u1) / (2 d)`` (the study writes
    ``V = r (u2 - u1) / 2``: a typo), no side slip.
    """

    states = ("x", "y", "theta")
    inputs = ("u1", "u2")
    Params = ZumoParams
    position = ("x", "y")
    heading = "theta"
    plot_states = ("theta",)
    units = {"x": "m", "y": "m", "theta": "rad", "u1": "rad/s", "u2": "rad/s"}
    holds_at_rest = True  # wheel speeds zero: the robot stands

    def rhs(self, x: ca.SX, u: ca.SX) -> ca.SX:
        theta = x[2]
        u1, u2 = u[0], u[1]
        r, d = self.params.r, self.params.d
        v = r * (u1 + u2) / 2
        omega = r * (u2 - u1) / (2 * d)
        return ca.vertcat(v * ca.cos(theta), v * ca.sin(theta), omega)
