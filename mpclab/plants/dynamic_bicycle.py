"""Dynamic bicycle (Study C): planar vehicle with yaw rate, side slip and speed as states.

Linear tyres (cornering stiffnesses ``Kf``, ``Kr`` per tyre, two tyres per axle)::

    Ff = -2 Kf (beta + lf r / V - delta)      Fr = -2 Kr (beta - lr r / V)
    px' = V cos(theta)    py' = V sin(theta)    theta' = r
    r'  = (lf Ff - lr Fr) / I
    beta' = (Ff + Fr) / (m V) - r
    V'  = a

**Guard for V near 0.** Every ``1/V`` is replaced by the regularized inverse

    inv_V = V / (V^2 + eps^2)        (eps = ``params.v_eps``, 0.1 m/s by default)

It is smooth (so the Jacobians and the linearizations the controllers use exist everywhere),
odd in ``V``, equal to 0 at ``V = 0`` (the tyre slip terms ``lf r / V`` and the ``1/(m V)``
factor vanish, so a vehicle at rest has finite derivatives: ``beta' = -r``), bounded by
``1/(2 eps)`` and within ``eps^2/V^2`` of ``1/V`` (1 % at V = 1 m/s, 0.25 % at 2 m/s). The
controllers linearize this same guarded model, so prediction and simulation agree.
"""

from __future__ import annotations

from dataclasses import dataclass

import casadi as ca

from mpclab.plants.base import Plant, register_plant


@dataclass
class DynamicBicycleParams:
    m: float = 2000.0     # mass [kg]
    lf: float = 1.4       # centre of gravity to front axle [m]
    lr: float = 1.6       # centre of gravity to rear axle [m]
    I: float = 4000.0     # yaw inertia [kg m^2]  # noqa: E741
    Kf: float = 12e3      # front cornering stiffness per tyre [N/rad]
    Kr: float = 11e3      # rear cornering stiffness per tyre [N/rad]
    v_eps: float = 0.1    # speed scale of the 1/V guard [m/s] (see the module docstring)

    def __post_init__(self) -> None:
        if self.v_eps <= 0:
            raise ValueError(f"params.v_eps must be > 0 (the 1/V guard), got {self.v_eps}")


@register_plant("dynamic_bicycle")
class DynamicBicycle(Plant):
    """``x = (px, py, theta, r, beta, V)``, ``u = (delta, a)``; the study's outputs are
    ``(px, py, theta, r, V)``.
    """

    states = ("px", "py", "theta", "r", "beta", "V")
    inputs = ("delta", "a")
    Params = DynamicBicycleParams
    plot_states = ("py", "theta", "V")

    def inv_speed(self, V: ca.SX) -> ca.SX:
        """The guarded ``1/V``: ``V / (V^2 + eps^2)``."""
        return V / (V**2 + self.params.v_eps**2)

    def rhs(self, x: ca.SX, u: ca.SX) -> ca.SX:
        p = self.params
        _, _, theta, r, beta, V = ca.vertsplit(x)
        delta, a = ca.vertsplit(u)
        inv_V = self.inv_speed(V)
        Ff = -2 * p.Kf * (beta + p.lf * r * inv_V - delta)
        Fr = -2 * p.Kr * (beta - p.lr * r * inv_V)
        return ca.vertcat(
            V * ca.cos(theta),
            V * ca.sin(theta),
            r,
            (p.lf * Ff - p.lr * Fr) / p.I,
            (Ff + Fr) * inv_V / p.m - r,
            a,
        )
