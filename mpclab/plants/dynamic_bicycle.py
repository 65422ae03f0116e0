"""Dynamic bicycle (Study C): planar vehicle with yaw rate, side slip and speed as states.

Linear tyres (cornering stiffnesses ``Kf``, ``Kr`` per tyre, two tyres per axle)::

    Ff = -2 Kf (beta + lf r / V - delta)      Fr = -2 Kr (beta - lr r / V)
    px' = V cos(theta)    py' = V sin(theta)    theta' = r
    r'  = (lf Ff - lr Fr) / I
    beta' = (Ff + Fr) / (m V) - r
    V'  = a

**Guard for V near 0.** Every ``1/V`` is :meth:`DynamicBicycle.inv_speed`, written once here
in CasADi (so the step, its Jacobians and every linearization derive from it)::

    inv_V = 1/V                                  for |V| >= v_min
    inv_V = (s/v_min) (3 - 3 s^2 + s^4), s = V/v_min   for |V| <  v_min

(``v_min = params.v_min``, 0.5 m/s by default). Above ``v_min`` the plant is the study's
exactly. Below, the odd quintic meets ``1/V`` at ``|V| = v_min`` with equal value, slope and
curvature (C^2, so IPOPT's Hessians are continuous), is 0 at ``V = 0`` (the slip terms
``lf r / V`` and the ``1/(m V)`` factor vanish: ``beta' = -r`` at rest) and is bounded by
``1.243 / v_min``. (It replaces ``V / (V^2 + eps^2)``, eps = 0.1 m/s, which changed the
plant by 1 % at 1 m/s and, there, entries of the discrete ``A`` by up to 8 % at dt = 0.02
and 11 % at dt = 0.05.)

**Stiffness and RK4 substeps.** The lateral modes (r, beta) are real, about ``-23/V`` and
``-25.8/V`` 1/s above ``v_min``; with the guard the fastest is at most 64.4 1/s at any speed
(at 0.33 m/s; :meth:`DynamicBicycle.lateral_eigenvalues`; at rest they are ``+-0.63j``).
RK4 with sub-step ``h = dt / substeps`` is stable for ``z = lambda h`` in ``[-2.785, 0]``; we
keep ``|z| <= 2`` (72 % of the limit; ``R(-2) = 0.33``, exact ``exp(-2) = 0.14``).
``conf/plant/dynamic_bicycle.yaml`` sets ``substeps: 2``: ``h`` = 25 ms at dt = 0.05
(``|z| <= 1.61`` at every speed; 0.65 at 1 m/s) and 10 ms at dt = 0.02 (``|z| <= 0.64``).
One step (``substeps: 1``) at dt = 0.05
leaves the region between 0.22 and 0.46 m/s and has ``|z| > 2`` from 0.14 to 0.65 m/s; at
dt = 0.02 one step would do (``|z| <= 1.29``), but one count serves both sample times.

The plant object is shared by the simulator and every controller's prediction, so the
substeps also refine the controllers' discrete models: the scheduled controller's models
then approach the exact zero-order-hold discretization the study's MATLAB (c2d) uses.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import casadi as ca
import numpy as np

from mpclab.plants.base import Plant, register_plant

#: RK4 is stable on the negative real axis for z = lambda h in [RK4_REAL_LIMIT, 0]
RK4_REAL_LIMIT = -2.785293563405282


@dataclass
class DynamicBicycleParams:
    m: float = 2000.0     # mass [kg]
    lf: float = 1.4       # centre of gravity to front axle [m]
    lr: float = 1.6       # centre of gravity to rear axle [m]
    I: float = 4000.0     # yaw inertia [kg m^2]  # noqa: E741
    Kf: float = 12e3      # front cornering stiffness per tyre [N/rad]
    Kr: float = 11e3      # rear cornering stiffness per tyre [N/rad]
    v_min: float = 0.5    # 1/V is exact for |V| >= v_min [m/s] (see the module docstring)

    def __post_init__(self) -> None:
        if not self.v_min > 0:
            raise ValueError(
                f"params.v_min must be > 0 (1/V is exact above it), got {self.v_min}"
            )


@register_plant("dynamic_bicycle")
class DynamicBicycle(Plant):
    """``x = (px, py, theta, r, beta, V)``, ``u = (delta, a)``; the study's outputs are
    ``(px, py, theta, r, V)``. ``substeps`` defaults to 2 (module docstring).
    """

    states = ("px", "py", "theta", "r", "beta", "V")
    inputs = ("delta", "a")
    Params = DynamicBicycleParams
    plot_states = ("py", "theta", "V")
    units = {"px": "m", "py": "m", "theta": "rad", "r": "rad/s", "beta": "rad", "V": "m/s",
             "delta": "rad", "a": "m/s²"}

    def __init__(
        self,
        params: Any = None,
        state_bounds: Mapping[str, Sequence[float]] | None = None,
        input_bounds: Mapping[str, Sequence[float]] | None = None,
        substeps: int = 2,
    ) -> None:
        super().__init__(params, state_bounds, input_bounds, substeps)

    def inv_speed(self, V: Any) -> Any:
        """The guarded ``1/V``: exact for ``|V| >= v_min``, a C^2 odd quintic below."""
        v = self.params.v_min
        inside = ca.fabs(V) < v
        exact = 1 / ca.if_else(inside, v, V)  # never divides by less than v_min
        s = V / v
        return ca.if_else(inside, s * (3 - 3 * s**2 + s**4) / v, exact)

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

    def lateral_eigenvalues(self, V: float) -> np.ndarray:
        """Eigenvalues [1/s] of ``d(r', beta')/d(r, beta)`` at speed ``V`` (straight driving)."""
        p = self.params
        iv = float(self.inv_speed(V))
        Cf, Cr = 2 * p.Kf, 2 * p.Kr
        a_rr = -(Cf * p.lf**2 + Cr * p.lr**2) * iv / p.I
        a_rb = -(Cf * p.lf - Cr * p.lr) / p.I
        a_br = -(Cf * p.lf - Cr * p.lr) * iv**2 / p.m - 1
        a_bb = -(Cf + Cr) * iv / p.m
        return np.linalg.eigvals(np.array([[a_rr, a_rb], [a_br, a_bb]]))

    def rk4_z(self, V: float, dt: float) -> float:
        """The largest ``|lambda h|`` of the lateral modes at speed ``V``, ``h = dt/substeps``."""
        return float(np.max(np.abs(self.lateral_eigenvalues(V)))) * dt / self.substeps


def rk4_amplification(z: complex) -> float:
    """``|R(z)|`` of classical RK4, ``R(z) = 1 + z + z^2/2 + z^3/6 + z^4/24``."""
    return abs(1 + z + z**2 / 2 + z**3 / 6 + z**4 / 24)
