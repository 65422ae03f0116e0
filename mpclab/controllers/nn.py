"""NN backend: a trained MLP imitating an MPC law, evaluated with NumPy (Study B).

No optimization and no prediction: the step computes the feature vector from the pose, the
goal and the range sensor's reading, runs the forward pass (a few matrix-vector products,
no scikit-learn call) and clips to the input bounds. ``x_pred`` is the current state only
(the network predicts nothing), so its horizon is 0.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mpclab.approx.features import FeatureSet, n_features
from mpclab.approx.mlp import MLP, activate
from mpclab.controllers.base import Controller, ControlStep, FloatArray, StepContext
from mpclab.errors import ConfigError
from mpclab.plants.base import Plant
from mpclab.registry import component

ROOT = Path(__file__).resolve().parents[2]


@dataclass
class NNConf:
    _target_: str = "mpclab.controllers.nn.NNController"
    weights: str = "???"      # .npz from mpclab.approx.train (relative to the repository root)
    dt: float = 0.2


@component("controller", "nn", NNConf)
class NNController(Controller):
    """The MPC law's imitation by a multilayer perceptron.

    Parameters
    ----------
    plant
        Injected; needs ``position`` and ``heading`` labels.
    weights
        Path of the ``.npz`` written by training; its metadata names the feature set.
    dt
        Sample time [s].
    """

    min_horizon = 0

    def __init__(self, plant: Plant, weights: str, dt: float = 0.2) -> None:
        super().__init__(plant, 0, dt)
        path = Path(weights)
        self.mlp = MLP.load(path if path.is_absolute() else ROOT / path)
        meta = self.mlp.meta
        self.features = FeatureSet(meta.get("features", "study"))
        self.min_range = float(meta.get("min_range", 0.05))
        if plant.heading is None:
            raise ConfigError("the NN controller needs a plant with a heading")
        self._ip = [plant.state_index(s) for s in (*plant.position, plant.heading)]
        if self.mlp.n_out != plant.nu:
            raise ConfigError(f"NN weights give {self.mlp.n_out} outputs, plant "
                              f"{type(plant).__name__} has {plant.nu} inputs")
        # output scaling folded into the last layer: the step is matrix-vector products only
        w, b = list(self.mlp.weights), list(self.mlp.biases)
        w[-1] = w[-1] * self.mlp.out_scale[:, None]
        b[-1] = b[-1] * self.mlp.out_scale + self.mlp.out_offset
        self._w = list(zip(w, b, strict=True))
        self._n_rays = self.mlp.n_in - n_features(self.features, 0)
        self._z = np.zeros(self.mlp.n_in)  # feature buffer, filled in place each step
        self._no_plan = np.zeros((0, plant.nu))

    def _features(self, x: FloatArray, ctx: StepContext) -> FloatArray:
        """The same vector as :func:`mpclab.approx.features.features`, built in place."""
        r = ctx.ranges
        if r.shape != (self._n_rays,):
            raise ConfigError(f"NN was trained on {self._n_rays} rays, the scenario's sensor "
                              f"gives {r.shape[0]}")
        z, n = self._z, self._n_rays
        p, g = x[self._ip], ctx.goal[self._ip]
        inv = z[-n:]
        np.divide(1.0, r, out=inv)  # IEEE: 1/inf = 0, a ray that sees nothing
        if self.features is FeatureSet.study:
            z[0:3] = p
            z[3:6] = g
            return z
        c, s = math.cos(p[2]), math.sin(p[2])
        dx, dy = g[0] - p[0], g[1] - p[1]
        err = g[2] - p[2]
        z[0:5] = (c * dx + s * dy, -s * dx + c * dy, math.hypot(dx, dy), math.sin(err),
                  math.cos(err))
        np.minimum(1.0, self.min_range * inv, out=inv)
        return z

    def _solve(self, t: float, x: FloatArray, ctx: StepContext) -> ControlStep:
        h = self._features(x, ctx)
        last = len(self._w) - 1
        for i, (w, b) in enumerate(self._w):
            h = w @ h + b
            if i < last:
                h = activate(self.mlp.activation, h)
        total = float(h.sum())
        if total != total:  # NaN from a degenerate input (e.g. a range of 0 inside a disc)
            return self._failed("nan_output", x)
        u = np.minimum(np.maximum(h, self.plant.u_lb), self.plant.u_ub)
        return ControlStep(u=u, x_pred=x[None, :], u_pred=self._no_plan, status="optimal")
