"""NN backend: a trained MLP imitating an MPC law, evaluated with NumPy (Study B).

No optimization and no prediction: the step computes the feature vector from the pose, the
goal and the range sensor's reading, runs the forward pass (a few matrix-vector products,
no scikit-learn call) and clips to the input bounds. ``x_pred`` is the current state only
(the network predicts nothing), so its horizon is 0.
"""

from __future__ import annotations

import math

import numpy as np

from mpclab.config.registry import component
from mpclab.config.root import config_file
from mpclab.controllers.base import Controller, ControlStep, FloatArray, SolveStatus, StepContext
from mpclab.core.errors import ConfigError
from mpclab.core.status import Problem
from mpclab.plants.base import Plant
from mpclab.policy.features import FeatureSet, n_features
from mpclab.policy.mlp import MLP, Activation, activate
from mpclab.world.scenario import Scenario


@component("controller", "nn", injected=("plant", "scenario"))
class NNController(Controller):
    """The MPC law's imitation by a multilayer perceptron.

    Parameters
    ----------
    plant
        Injected; needs ``position`` and ``heading`` labels.
    weights
        Path of the ``.npz`` written by training (relative: from the working folder, else
        from the config folder); its metadata names the feature set.
    dt
        Sample time [s].
    scenario
        Injected when built from config: its range sensor must give the rays the net was
        trained on.
    """

    min_horizon = 0

    #: a learned policy evaluated exactly: no optimal control problem is solved
    solved_problem = Problem.policy

    def __init__(
        self, plant: Plant, weights: str, dt: float = 0.2, scenario: Scenario | None = None,
    ) -> None:
        super().__init__(plant, 0, dt)
        try:
            self.mlp = MLP.load(config_file(weights) or weights)
        except (ValueError, FileNotFoundError) as exc:
            raise ConfigError(f"controller.weights: {exc}") from None
        meta = self.mlp.meta
        self.features = FeatureSet(meta.get("features", "study"))
        self.min_range = float(meta.get("min_range", 0.05))
        if plant.heading is None:
            raise ConfigError("the NN controller needs a plant with a heading")
        ip = [plant.state_index(s) for s in (*plant.position, plant.heading)]
        # a slice (a view, no copy) when the pose is stored contiguously, as for the Zumo
        self._ip = slice(ip[0], ip[0] + 3) if ip == list(range(ip[0], ip[0] + 3)) else ip
        if self.mlp.n_out != plant.nu:
            raise ConfigError(f"controller.weights: the net gives {self.mlp.n_out} outputs, plant "
                              f"{type(plant).__name__} has {plant.nu} inputs")
        # output scaling folded into the last layer: the step is matrix-vector products only
        w, b = list(self.mlp.weights), list(self.mlp.biases)
        w[-1] = w[-1] * self.mlp.out_scale[:, None]
        b[-1] = b[-1] * self.mlp.out_scale + self.mlp.out_offset
        # bias as the last column, inputs with a constant 1 appended: one product per layer
        self._w = [np.ascontiguousarray(np.column_stack([wi, bi])) for wi, bi in zip(w, b,
                                                                                    strict=True)]
        self._n_rays = self.mlp.n_in - n_features(self.features, 0)
        n_sensed = getattr(getattr(scenario, "sensor", None), "n_rays", None)
        if scenario is not None and n_sensed != self._n_rays:
            raise ConfigError(
                f"controller.weights: the net takes {self._n_rays} range rays, the scenario "
                f"{scenario.name!r} gives {n_sensed or 0} (scenario.sensor.n_rays)"
            )
        self._ranges_shape = (self._n_rays,)
        # buffers reused every step: the features and each layer's output, each with the 1;
        # the step walks this precomputed plan: (weights, input, output view, activate?)
        self._z = np.ones(self.mlp.n_in + 1)
        bufs = [self._z] + [np.ones(wi.shape[0] + 1) for wi in w]
        last = len(w) - 1
        self._layers = [(wk, bufs[i], bufs[i + 1][:-1], i < last)
                        for i, wk in enumerate(self._w)]
        self._out = bufs[-1][:-1]
        act = self.mlp.activation
        self._act = ((lambda a: np.tanh(a, out=a)) if act is Activation.tanh
                     else (lambda a: np.copyto(a, activate(act, a))))
        self._no_plan = np.zeros((0, plant.nu))

    def _features(self, x: FloatArray, ctx: StepContext) -> FloatArray:
        """The same vector as :func:`mpclab.policy.features.features`, built in place."""
        r = ctx.ranges
        if r.shape != self._ranges_shape:
            raise ConfigError(f"NN was trained on {self._n_rays} rays, the scenario's sensor "
                              f"gives {r.shape[0]}")
        z, n = self._z, self._n_rays
        p, g = x[self._ip], ctx.goal[self._ip]
        inv = z[-n - 1 : -1]
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
        self._features(x, ctx)
        for w, src, dst, hidden in self._layers:
            np.dot(w, src, out=dst)  # the trailing 1 of src multiplies the bias column
            if hidden:
                self._act(dst)
        u = self._out.copy()
        for v in u.tolist():
            if v != v:  # NaN from a degenerate input (e.g. a range of 0 inside a disc)
                return self._failed(SolveStatus.failed, x, "nan_output")
        np.minimum(np.maximum(u, self.plant.u_lb, out=u), self.plant.u_ub, out=u)
        # an exact evaluation: nothing to iterate, so nothing short of converged
        return ControlStep(u=u, x_pred=x[None, :], u_pred=self._no_plan,
                           status=SolveStatus.converged, solver_status="evaluated")

