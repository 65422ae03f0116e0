"""Feature vectors for hand-built sensor readings."""

from __future__ import annotations

import numpy as np
import pytest

from mpclab.policy.features import FeatureSet, features, n_features


def readings() -> np.ndarray:
    d = np.full(20, np.inf)
    d[0], d[5], d[19] = 0.1, 0.25, 0.04
    return d


def test_study_features_are_pose_goal_and_inverse_ranges() -> None:
    z = features("study", [0.4, 0.8, 0.5], [0.4, 0.4, 0.0], readings())
    assert z.shape == (26,) == (n_features("study", 20),)
    np.testing.assert_array_equal(z[:6], [0.4, 0.8, 0.5, 0.4, 0.4, 0.0])
    expected = np.zeros(20)
    expected[0], expected[5], expected[19] = 10.0, 4.0, 25.0  # 1/d, and 1/inf = 0
    np.testing.assert_allclose(z[6:], expected, rtol=1e-15)


def test_body_features_put_the_goal_in_the_robot_frame() -> None:
    # robot at (1, 1) facing +y; goal at (1, 2) facing +x: the goal is straight ahead
    z = features(FeatureSet.body, [1.0, 1.0, np.pi / 2], [1.0, 2.0, 0.0], readings(), 0.05)
    assert z.shape == (25,)
    np.testing.assert_allclose(z[:5], [1.0, 0.0, 1.0, -1.0, 0.0], atol=1e-15)
    expected = np.zeros(20)
    expected[0], expected[5], expected[19] = 0.5, 0.2, 1.0  # min(1, 0.05/d)
    np.testing.assert_allclose(z[5:], expected, rtol=1e-15)


def test_batch_equals_rows() -> None:
    rng = np.random.default_rng(0)
    P = rng.uniform(-1, 1, (7, 3))
    D = np.where(rng.random((7, 20)) < 0.5, np.inf, rng.uniform(0.03, 0.3, (7, 20)))
    for kind in FeatureSet:
        Z = features(kind, P, [0.4, 0.4, 0.0], D)
        for i in range(7):
            # a batch and a row take different vectorized paths (SIMD sin/cos may differ
            # in the last bit on some CPUs): equal to rounding, not bit for bit
            np.testing.assert_allclose(Z[i], features(kind, P[i], [0.4, 0.4, 0.0], D[i]),
                                       rtol=1e-13, atol=1e-15)
    with pytest.raises(ValueError, match="3 rows for 7 poses"):
        features("study", P, [0, 0, 0], D[:3])


def test_visited_features_equal_what_the_loop_sensed(tmp_path) -> None:
    """Features rebuilt from logged states (the evaluation's compiled timing) equal the
    features of the readings the closed loop itself recorded (the dataset recorder)."""
    import pandas as pd

    from mpclab.approx.evaluate import visited_features
    from mpclab.policy.mlp import MLP
    from mpclab.runner.loop import simulate
    from mpclab.runner.single_run import build_run, compose

    cfg = compose(["+experiment=zumo_nn_data", "recorder=dataset", "seed=100003",
                   "scenario.t_max=1.0", "figures.enabled=false"])
    run = build_run(cfg, tmp_path)
    res = simulate(run)
    rows = pd.read_parquet(tmp_path / "dataset.parquet")
    from pathlib import Path

    mlp = MLP.load(Path(__file__).resolve().parents[1] / "conf/weights/zumo_nn.npz")
    steps = res.steps.dropna(subset=["solve_time_s"])
    got = visited_features(mlp, run, steps[list(run.plant.states)])
    ranges = rows[[c for c in rows.columns if c.startswith("d") and c[1:].isdigit()]]
    want = features("study", rows[["x", "y", "theta"]], rows[["x0", "y0", "theta0"]], ranges)
    assert len(got) == len(rows) > 0
    np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-12)  # batched vs per-step sensor
