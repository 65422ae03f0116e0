"""Train the MLP that imitates the MPC law, with scikit-learn's ``MLPRegressor``.

Rows the expert solved to convergence (status ``converged``, no fallback) become
``(features, u)`` pairs; whole runs are held out (``held_out`` of them), so the held-out
error is measured on trajectories the net never saw. Inputs are standardized, outputs scaled
to the input bounds (``u / u_max`` for symmetric bounds, the study's ``u / 10``); both
scalings are folded into the saved :class:`~mpclab.policy.mlp.MLP`.

    uv run python -m mpclab.approx.train DATA.parquet -o weights.npz [train.hidden=[64,64] ...]
"""

from __future__ import annotations

import argparse
import importlib.util
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from omegaconf import OmegaConf

from mpclab.approx import dataset
from mpclab.core.errors import ConfigError, exit_on_bad_input
from mpclab.policy.features import FeatureSet, features
from mpclab.policy.mlp import MLP, Activation


@dataclass
class TrainConf:
    features: FeatureSet = FeatureSet.study   # study (26) or body (better conditioned)
    min_range: float = 0.05                   # d_min of the body features' clipped 1/d [m]
    hidden: list[int] = field(default_factory=lambda: [100])   # the study: 26-100-2
    activation: Activation = Activation.tanh
    held_out: float = 0.15                    # fraction of runs held out
    max_iter: int = 400
    tol: float = 1.0e-6                       # stop when the loss improves less for 10 epochs
    alpha: float = 1.0e-4                     # L2 penalty
    learning_rate_init: float = 1.0e-3
    batch_size: int = 256
    seed: int = 0


@dataclass
class TrainReport:
    n_train: int
    n_test: int
    runs_train: int
    runs_test: int
    mse_train: float          # (rad/s)^2, physical units
    mse_test: float           # (rad/s)^2
    mse_test_study: float     # in the study's units (u / 10)^2
    iterations: int
    features: str
    hidden: list[int]


def pairs(data: pd.DataFrame, conf: TrainConf, inputs: list[str]) -> tuple[np.ndarray, ...]:
    """``(Z, U, run)`` of the rows the expert solved."""
    # "optimal": how datasets recorded before the solve statuses labelled an IPOPT success
    ok = data["status"].isin(["converged", "optimal"]) & ~data["fallback"].astype(bool)
    d = data[ok]
    ray_cols = sorted((c for c in d.columns if c[0] == "d" and c[1:].isdigit()),
                      key=lambda c: int(c[1:]))
    Z = features(conf.features, d[["x", "y", "theta"]].to_numpy(float),
                 d[["x0", "y0", "theta0"]].to_numpy(float), d[ray_cols].to_numpy(float),
                 conf.min_range)
    return Z, d[inputs].to_numpy(float), d["run"].to_numpy()


def require_trainer() -> None:
    """Raise :class:`ConfigError` unless scikit-learn (the ``nn`` extra) is installed: training
    needs it, running a trained net does not."""
    if importlib.util.find_spec("sklearn") is None:
        raise ConfigError("training the net needs scikit-learn: uv sync --extra nn")


def train(
    data: pd.DataFrame,
    conf: TrainConf,
    inputs: list[str],
    lb: np.ndarray,
    ub: np.ndarray,
    meta: dict[str, Any] | None = None,
) -> tuple[MLP, TrainReport]:
    """Fit the net on ``data`` (a merged dataset); return it and the held-out errors."""
    require_trainer()  # the `nn` extra: imported here, so that a net runs without it
    from sklearn.exceptions import ConvergenceWarning
    from sklearn.neural_network import MLPRegressor

    Z, U, runs = pairs(data, conf, inputs)
    if len(Z) == 0:
        raise ValueError("the dataset has no rows the expert solved")
    rng = np.random.default_rng(conf.seed)
    names = np.unique(runs)
    n_test = max(1, round(conf.held_out * len(names))) if len(names) > 1 else 0
    test_runs = set(rng.permutation(names)[:n_test])
    test = np.array([r in test_runs for r in runs])
    lb, ub = np.asarray(lb, float), np.asarray(ub, float)
    scale, offset = (ub - lb) / 2, (ub + lb) / 2
    mean = Z[~test].mean(axis=0)
    std = Z[~test].std(axis=0)
    std[std < 1e-9] = 1.0
    model = MLPRegressor(
        hidden_layer_sizes=tuple(conf.hidden), activation=str(conf.activation),
        alpha=conf.alpha, learning_rate_init=conf.learning_rate_init,
        batch_size=min(conf.batch_size, int((~test).sum())), max_iter=conf.max_iter, tol=conf.tol,
        random_state=conf.seed,
    )
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ConvergenceWarning)
        model.fit((Z[~test] - mean) / std, (U[~test] - offset) / scale)
    mlp = MLP.from_sklearn(model, mean, std, scale, offset, meta={
        **(meta or {}), "features": str(conf.features), "min_range": conf.min_range,
        "inputs": list(inputs),
    })
    pred = mlp.forward(Z)

    def mse(mask: np.ndarray, unit: float = 1.0) -> float:
        return float(np.mean(((pred[mask] - U[mask]) / unit) ** 2)) if mask.any() else float("nan")

    report = TrainReport(
        n_train=int((~test).sum()), n_test=int(test.sum()), runs_train=len(names) - n_test,
        runs_test=n_test, mse_train=mse(~test), mse_test=mse(test),
        mse_test_study=mse(test, 10.0), iterations=int(model.n_iter_),
        features=str(conf.features), hidden=list(conf.hidden),
    )
    return mlp, report


def main(argv: list[str] | None = None) -> TrainReport:
    ap = argparse.ArgumentParser(prog="python -m mpclab.approx.train",
                                 description="Train the NN on a merged dataset.")
    ap.add_argument("data", type=Path)
    ap.add_argument("-o", "--output", type=Path, required=True)
    ap.add_argument("--bounds", type=float, nargs=2, default=(-10.0, 10.0),
                    help="symmetric input bounds of both wheels [rad/s]")
    ap.add_argument("overrides", nargs="*", help="train.KEY=VALUE")
    args = ap.parse_intermixed_args(argv)  # overrides before or after -o
    dotlist = [o.removeprefix("train.") for o in args.overrides]
    try:  # a typo'd or mistyped option, no dataset or not one, no trainer
        conf = OmegaConf.merge(OmegaConf.structured(TrainConf), OmegaConf.from_dotlist(dotlist))
        data, meta = dataset.read(args.data)
        require_trainer()
    except Exception as exc:  # noqa: BLE001  (bad input is one message; a bug re-raised)
        exit_on_bad_input(ap, exc)
    inputs = ["u1", "u2"]
    lb, ub = np.full(2, args.bounds[0]), np.full(2, args.bounds[1])
    mlp, report = train(data, OmegaConf.to_object(conf), inputs, lb, ub,
                        {"dataset": str(args.data), "config_hashes": meta.get("config_hashes")})
    mlp.save(args.output)
    print(report)
    return report


if __name__ == "__main__":
    main()
