"""Training: the net learns a known law, held-out runs are disjoint, failed rows are left out."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from mpclab.approx.train import TrainConf, pairs, train
from mpclab.policy.features import FeatureSet, features

pytestmark = pytest.mark.needs("nn")

RNG = np.random.default_rng(11)


def synthetic(n_runs: int = 40, per_run: int = 25) -> pd.DataFrame:
    """Rows whose input is a known smooth law of the body-frame features."""
    n = n_runs * per_run
    pose = RNG.uniform([-0.1, -0.1, -np.pi], [1.1, 1.1, np.pi], (n, 3))
    goal = np.tile([0.4, 0.4, 0.0], (n, 1))
    d = np.where(RNG.random((n, 20)) < 0.8, np.inf, RNG.uniform(0.05, 0.3, (n, 20)))
    z = features("body", pose, goal, d)
    u = 10 * np.tanh(np.column_stack([z[:, 0] - z[:, 1], z[:, 0] + 2 * z[:, 1]]))
    data = pd.DataFrame(np.column_stack([pose, goal, d, u]),
                        columns=["x", "y", "theta", "x0", "y0", "theta0",
                                 *[f"d{i}" for i in range(20)], "u1", "u2"])
    data["run"] = np.repeat([f"run{i}" for i in range(n_runs)], per_run)
    data["status"] = "converged"
    data["fallback"] = False
    return data


def test_learns_a_known_law_on_held_out_runs() -> None:
    data = synthetic()
    conf = TrainConf(features=FeatureSet.body, hidden=[32], max_iter=300, seed=1)
    mlp, report = train(data, conf, ["u1", "u2"], np.full(2, -10.0), np.full(2, 10.0))
    variance = float(np.var(data[["u1", "u2"]].to_numpy()))
    assert report.runs_test == 6 and report.runs_train == 34  # 15 % of 40 runs
    assert report.n_test == 6 * 25
    assert report.mse_test < 0.05 * variance, (report.mse_test, variance)
    assert report.mse_test_study == pytest.approx(report.mse_test / 100, rel=1e-12)  # (u / 10)^2
    assert mlp.meta["features"] == "body" and mlp.sizes == [25, 32, 2]


def test_only_rows_the_expert_solved_are_used() -> None:
    data = synthetic(4, 10)
    data.loc[3, "status"] = "infeasible"
    data.loc[7, "fallback"] = True
    Z, U, runs = pairs(data, TrainConf(), ["u1", "u2"])
    assert len(Z) == 38 and Z.shape[1] == 26
    np.testing.assert_array_equal(U, data.drop(index=[3, 7])[["u1", "u2"]].to_numpy())
