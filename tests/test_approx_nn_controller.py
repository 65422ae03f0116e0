"""The NN controller: its features and forward pass equal the reference implementations."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from mpclab.controllers.base import StepContext
from mpclab.controllers.nn.controller import NNController
from mpclab.plants.zumo import Zumo
from mpclab.policy.features import FeatureSet, features, n_features
from mpclab.policy.mlp import MLP

RNG = np.random.default_rng(7)


def random_mlp(kind: FeatureSet, n_rays: int = 20) -> MLP:
    n_in = n_features(kind, n_rays)
    return MLP(
        [RNG.standard_normal((16, n_in)) * 0.3, RNG.standard_normal((2, 16))],
        [RNG.standard_normal(16), RNG.standard_normal(2)],
        "tanh", out_scale=[10.0, 10.0], meta={"features": str(kind), "min_range": 0.05},
    )


@pytest.mark.parametrize("kind", list(FeatureSet))
def test_step_equals_features_then_forward_then_clip(tmp_path: Path, kind: FeatureSet) -> None:
    mlp = random_mlp(kind)
    plant = Zumo(input_bounds={"u1": [-10, 10], "u2": [-10, 10]})
    ctrl = NNController(plant, str(mlp.save(tmp_path / "w.npz")), dt=0.2)
    goal = np.array([0.4, 0.4, 0.0])
    clipped = 0
    for _ in range(50):
        x = RNG.uniform([-0.1, -0.1, -np.pi], [1.1, 1.1, np.pi])
        r = np.where(RNG.random(20) < 0.6, np.inf, RNG.uniform(0.02, 0.3, 20))
        res = ctrl.step(0.0, x, StepContext(goal=goal, target=np.tile(goal, (1, 1)), ranges=r))
        expected = np.clip(mlp.forward(features(kind, x, goal, r)), -10, 10)
        np.testing.assert_allclose(res.u, expected, rtol=1e-12, atol=1e-12)
        assert res.ok and res.x_pred.shape == (1, 3) and res.u_pred.shape == (0, 2)
        clipped += int(np.any(np.abs(mlp.forward(features(kind, x, goal, r))) > 10))
    assert clipped > 0  # the clip was exercised


def test_wrong_sensor_size_is_a_clear_error(tmp_path: Path) -> None:
    plant = Zumo()
    ctrl = NNController(plant, str(random_mlp(FeatureSet.study).save(tmp_path / "w.npz")))
    res = ctrl.step(0.0, np.zeros(3), StepContext(goal=np.zeros(3), target=np.zeros((1, 3)),
                                                  ranges=np.full(12, np.inf)))
    assert res.fallback and res.status == "exception" and res.solver_status == "ConfigError"
    assert "trained on 20 rays" in res.info["error"]


def test_nn_runs_in_the_closed_loop(tmp_path: Path, run_cfg) -> None:
    weights = random_mlp(FeatureSet.body).save(tmp_path / "w.npz")
    result, out = run_cfg(["plant=zumo", "scenario=zumo_one_obstacle", "controller=nn",
                           f"controller.weights={weights}", "scenario.t_max=2.0"])
    s = result.summary
    assert s["controller"] == "nn" and s["status"] != "error", s.get("error")
    hz = pd.read_parquet(out / "horizons.parquet")
    assert len(hz) == s["n_steps"]  # one point per step: the NN predicts nothing
