"""The EKF localization (``sim.localization.source=ekf``): its covariance against Monte Carlo,
the wheel scale it learns, its consistency in the closed loop, its arrival rule, its errors."""

from __future__ import annotations

import math

import numpy as np
import pytest

from mpclab.core.errors import ConfigError
from mpclab.plants.zumo import Zumo
from mpclab.world.scenario import Scenario
from mpclab.world.sim_world import SimWorld

ZUMO = Zumo(input_bounds={"u1": [-10, 10], "u2": [-10, 10]})
EKF = ["+experiment=zumo_bug2", "scenario=zumo_random", "sim.plant_params.r=0.021",
       "sim.localization.source=ekf", "sim.localization.fix.period_s=1.0",
       "sim.localization.fix.std.position=0.005", "sim.localization.fix.std.heading=0.02"]


def _world(seed: int, **localization) -> SimWorld:
    return SimWorld(ZUMO, seed=seed, dt=0.2, localization=localization)


def _drive(world: SimWorld, periods: int) -> tuple[np.ndarray, np.ndarray]:
    """A curved drive with a constant input: (true state, estimate) at the end."""
    world.reset(2)
    x = np.zeros(3)
    world.measure(x)
    u = np.array([6.0, 8.0])
    for _ in range(periods):
        x = world.advance(x, world.timing(u, u[None, :], 0.0))
    return x, world.odometry.estimate


def test_covariance_matches_monte_carlo_of_the_encoder_noise() -> None:
    """Encoder noise alone, no fix due: the position error's covariance over 1500 seeds
    agrees with the filter's ``P`` (the linearization of the model's own step) to 12 %."""
    options = dict(source="ekf", odometry={"input_std": {"u1": 0.3, "u2": 0.3}},
                   fix={"period_s": 100.0}, ekf={"model_rel_std": 0.0})
    errors = []
    for seed in range(1500):
        world = _world(seed, **options)
        x, estimate = _drive(world, 10)
        errors.append((estimate - x)[:2])
    sample = np.cov(np.array(errors).T)
    P = world.ekf.P[:2, :2]
    assert np.linalg.norm(sample - P) <= 0.12 * np.linalg.norm(P)


def test_it_learns_the_wheel_scale_and_stays_consistent(run_cfg) -> None:
    """A wheel 5 % larger than the model's (r 0.021 against 0.020): the filter's input scales
    come to about 0.05, the estimate's error stays within a few standard deviations (mean
    normalized error squared near 2, its expectation), and the run arrives."""
    result, _ = run_cfg([*EKF, "seed=0"])
    s = result.summary
    assert s["status"] == "arrived", s
    assert s["localization_input_scales"] == pytest.approx([0.05, 0.05], abs=0.01)
    assert 0.5 < s["localization_nees_mean"] < 6.0, s
    assert s["localization_error_max_m"] < 4 * s["localization_std_max_m"], s


def test_the_arrival_rule_spares_the_estimates_doubt() -> None:
    world = _world(0, source="ekf", fix={"period_s": 100.0},
                   odometry={"input_std": {"u1": 0.3, "u2": 0.3}})
    _drive(world, 10)
    doubt = world.arrival_doubt()
    assert doubt == pytest.approx(1.6449 * world.ekf.position_std(), rel=1e-3) and doubt > 0
    assert _world(0).arrival_doubt() == 0.0


def test_an_ekf_without_a_measurement_is_refused() -> None:
    with pytest.raises(ConfigError, match=r"needs a measurement.*fix\.period_s"):
        _world(0, source="ekf")
    with pytest.raises(ConfigError, match="acts only with sim.localization.source=ekf"):
        _world(0, source="odometry", ekf={"model_rel_std": 0.1})
    assert math.isfinite(_world(0, source="ekf", fix={"period_s": 1.0}).ekf.model_rel_std)


def test_arrival_with_doubt_needs_the_doubt_to_spare() -> None:
    scen = Scenario(ZUMO, "s", {"x": 0, "y": 0, "theta": 0}, {"x": 1, "y": 1, "theta": 0},
                    {"weights": {"x": 1.0, "y": 1.0}, "threshold": 0.0025})  # 5 cm
    x = np.array([1.04, 1.0, 0.0])
    assert scen.arrived(x) and scen.arrived(x, doubt=0.009)
    assert not scen.arrived(x, doubt=0.011)
