"""The plant's derived functions against independent answers."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from mpclab.core.errors import ConfigError
from mpclab.plants.kinematic_car import KinematicCar

RNG = np.random.default_rng(0)


def car_rhs_numpy(x: np.ndarray, u: np.ndarray, l: float = 1.0) -> np.ndarray:
    """Study A's equations written out by hand, independent of the CasADi definition."""
    _, _, th, v, phi = x
    return np.array([v * np.cos(th), v * np.sin(th), v * np.tan(phi) / l, u[0], u[1]])


def random_points(n: int = 5) -> list[tuple[np.ndarray, np.ndarray]]:
    out = []
    for _ in range(n):
        x = RNG.uniform([-5, -5, -np.pi, -3, -0.6], [5, 5, np.pi, 3, 0.6])
        u = RNG.uniform([-5, -2], [5, 2])
        out.append((x, u))
    return out


def test_rhs_matches_hand_written_equations() -> None:
    car = KinematicCar(params={"l": 1.7})
    for x, u in random_points():
        np.testing.assert_allclose(
            np.asarray(car.f(x, u)).ravel(), car_rhs_numpy(x, u, 1.7), rtol=1e-12, atol=1e-12
        )


@pytest.mark.parametrize("dt", [0.05, 0.1, 0.3])
def test_jacobians_match_central_differences(dt: float) -> None:
    car = KinematicCar()
    eps = 1e-6
    for x, u in random_points():
        A, B = car.jacobians(x, u, dt)
        A_fd = np.column_stack([
            (car.step(x + eps * e, u, dt) - car.step(x - eps * e, u, dt)) / (2 * eps)
            for e in np.eye(car.nx)
        ])
        B_fd = np.column_stack([
            (car.step(x, u + eps * e, dt) - car.step(x, u - eps * e, dt)) / (2 * eps)
            for e in np.eye(car.nu)
        ])
        np.testing.assert_allclose(A, A_fd, rtol=1e-6, atol=1e-7)
        np.testing.assert_allclose(B, B_fd, rtol=1e-6, atol=1e-7)


def test_rk4_converges_with_fourth_order() -> None:
    car = KinematicCar()
    x0 = np.array([0.0, 0.0, 0.3, 2.0, 0.2])
    u = np.array([1.0, 0.8])
    T = 1.0
    ref = solve_ivp(lambda t, x: car_rhs_numpy(x, u), (0, T), x0, rtol=1e-12, atol=1e-12).y[:, -1]
    errors = []
    for n in (5, 10, 20, 40):
        x = x0.copy()
        for _ in range(n):
            x = car.step(x, u, T / n)
        errors.append(np.linalg.norm(x - ref))
    orders = np.log2(np.array(errors[:-1]) / np.array(errors[1:]))
    assert np.all((orders > 3.7) & (orders < 4.3)), orders


def test_substeps_refine_the_step() -> None:
    x, u = np.array([0.0, 0.0, 0.3, 2.0, 0.2]), np.array([1.0, 0.8])
    fine = KinematicCar(substeps=4).step(x, u, 0.4)
    coarse = KinematicCar()
    expected = x
    for _ in range(4):
        expected = coarse.step(expected, u, 0.1)
    np.testing.assert_allclose(fine, expected, rtol=1e-13, atol=1e-13)


def test_linearization_is_exact_at_its_point_and_first_order_nearby() -> None:
    car = KinematicCar()
    for x, u in random_points():
        A, B, c = car.linearize(x, u, 0.1)
        np.testing.assert_allclose(A @ x + B @ u + c, car.step(x, u, 0.1), rtol=0, atol=1e-12)
        dx, du = 1e-3 * RNG.standard_normal(5), 1e-3 * RNG.standard_normal(2)
        err = A @ (x + dx) + B @ (u + du) + c - car.step(x + dx, u + du, 0.1)
        assert np.linalg.norm(err) < 1e-4  # second order in the perturbation


def test_linearize_trajectory_equals_pointwise() -> None:
    car = KinematicCar()
    X = RNG.uniform(-1, 1, (7, 5))
    U = RNG.uniform(-1, 1, (7, 2))
    A, B, c = car.linearize_trajectory(X, U, 0.1)
    assert A.shape == (7, 5, 5) and B.shape == (7, 5, 2) and c.shape == (7, 5)
    for k in range(7):
        Ak, Bk, ck = car.linearize(X[k], U[k], 0.1)
        np.testing.assert_allclose(A[k], Ak, rtol=1e-14, atol=1e-15)
        np.testing.assert_allclose(B[k], Bk, rtol=1e-14, atol=1e-15)
        np.testing.assert_allclose(c[k], ck, atol=1e-15)


def test_bounds_and_params_are_checked() -> None:
    car = KinematicCar(input_bounds={"a": [-10, 10]}, state_bounds={"phi": [-0.5, 0.5]})
    np.testing.assert_array_equal(car.u_lb, [-10, -np.inf])
    np.testing.assert_array_equal(car.clip_input([20, 7]), [10, 7])
    msg = r"unknown key 'phy' in input_bounds.*Valid keys: a, phi_dot"
    with pytest.raises(ConfigError, match=msg):
        KinematicCar(input_bounds={"phy": [0, 1]})
    with pytest.raises(ConfigError, match=r"unknown key 'wheelbase'.*Valid keys: l"):
        KinematicCar(params={"wheelbase": 2.0})
    with pytest.raises(ValueError, match="lower bound 1.0 exceeds upper bound 0.0"):
        KinematicCar(input_bounds={"a": [1, 0]})
    with pytest.raises(ValueError, match="unknown state label 'speed'; valid states: px, py"):
        car.state_index("speed")
