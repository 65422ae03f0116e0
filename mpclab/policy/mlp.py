"""A multilayer perceptron evaluated with NumPy: weights from scikit-learn, saved as ``.npz``.

Input standardization is folded into the first layer and output scaling kept as
``u = y * out_scale + out_offset``, so a forward pass is a few matrix-vector products.
"""

from __future__ import annotations

import json
import zipfile
from dataclasses import dataclass, field
from enum import StrEnum
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from mpclab.core.errors import ConfigError

FloatArray = npt.NDArray[np.float64]


class Activation(StrEnum):
    tanh = "tanh"
    relu = "relu"
    identity = "identity"
    logistic = "logistic"


def activate(kind: Activation, z: FloatArray) -> FloatArray:
    """The hidden-layer activation ``kind`` applied elementwise."""
    if kind is Activation.tanh:
        return np.tanh(z)
    if kind is Activation.relu:
        return np.maximum(z, 0.0)
    if kind is Activation.logistic:
        return 1.0 / (1.0 + np.exp(-z))
    return z


@dataclass
class MLP:
    """Hidden layers with one activation, a linear output layer, scaled outputs.

    Attributes
    ----------
    weights
        ``W_l`` of shape ``(n_out_l, n_in_l)``.
    biases
        ``b_l`` of shape ``(n_out_l,)``.
    activation
        Hidden-layer activation.
    out_scale, out_offset
        Physical output ``u = y * out_scale + out_offset``.
    meta
        Anything worth keeping with the weights (feature set, dataset hash, bounds, ...).
    """

    weights: list[FloatArray]
    biases: list[FloatArray]
    activation: Activation = Activation.tanh
    out_scale: FloatArray = field(default_factory=lambda: np.ones(1))
    out_offset: FloatArray = field(default_factory=lambda: np.zeros(1))
    meta: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.activation = Activation(self.activation)
        self.weights = [np.ascontiguousarray(w, dtype=float) for w in self.weights]
        self.biases = [np.asarray(b, dtype=float).reshape(-1) for b in self.biases]
        for i, (w, b) in enumerate(zip(self.weights, self.biases, strict=True)):
            if w.shape[0] != b.shape[0]:
                raise ValueError(f"layer {i}: weights {w.shape} do not match bias {b.shape}")
            if i and w.shape[1] != self.weights[i - 1].shape[0]:
                raise ValueError(
                    f"layer {i} takes {w.shape[1]} inputs, layer {i - 1} gives "
                    f"{self.weights[i - 1].shape[0]}"
                )
        self.out_scale = np.broadcast_to(np.asarray(self.out_scale, float), (self.n_out,)).copy()
        self.out_offset = np.broadcast_to(np.asarray(self.out_offset, float), (self.n_out,)).copy()

    @property
    def n_in(self) -> int:
        return self.weights[0].shape[1]

    @property
    def n_out(self) -> int:
        return self.weights[-1].shape[0]

    @property
    def sizes(self) -> list[int]:
        return [self.n_in] + [w.shape[0] for w in self.weights]

    def forward(self, z: npt.ArrayLike) -> FloatArray:
        """Outputs for inputs ``(n_in,)`` or ``(N, n_in)``, in physical units."""
        h = np.asarray(z, dtype=float)
        last = len(self.weights) - 1
        for i, (w, b) in enumerate(zip(self.weights, self.biases, strict=True)):
            h = h @ w.T + b
            if i < last:
                h = activate(self.activation, h)
        return h * self.out_scale + self.out_offset

    # ------------------------------------------------------------------ conversion
    @classmethod
    def from_sklearn(
        cls,
        model: Any,
        in_mean: npt.ArrayLike,
        in_scale: npt.ArrayLike,
        out_scale: npt.ArrayLike,
        out_offset: npt.ArrayLike = 0.0,
        meta: dict[str, Any] | None = None,
    ) -> MLP:
        """From a fitted ``MLPRegressor`` trained on ``(z - in_mean) / in_scale``."""
        if getattr(model, "out_activation_", "identity") != "identity":
            raise ValueError(
                f"only a linear output layer is supported, got {model.out_activation_}"
            )
        mean = np.asarray(in_mean, dtype=float)
        scale = np.asarray(in_scale, dtype=float)
        weights = [np.asarray(c, dtype=float).T for c in model.coefs_]
        biases = [np.asarray(b, dtype=float) for b in model.intercepts_]
        # fold standardization into layer 0: W (z - m) / s + b = (W / s) z + (b - (W / s) m)
        w0 = weights[0] / scale
        biases[0] = biases[0] - w0 @ mean
        weights[0] = w0
        return cls(
            weights,
            biases,
            Activation(model.activation),
            np.asarray(out_scale, float),
            np.asarray(out_offset, float),
            dict(meta or {}),
        )

    def save(self, path: str | Path) -> Path:
        path = Path(path)
        arrays: dict[str, Any] = {f"W{i}": w for i, w in enumerate(self.weights)}
        arrays |= {f"b{i}": b for i, b in enumerate(self.biases)}
        header = {
            "activation": str(self.activation),
            "n_layers": len(self.weights),
            "meta": self.meta,
        }
        np.savez(
            path,
            out_scale=self.out_scale,
            out_offset=self.out_offset,
            header=np.array(json.dumps(header)),
            **arrays,
        )
        return path

    @classmethod
    def load(cls, path: str | Path) -> MLP:
        path = Path(path)
        if not path.exists():
            raise FileNotFoundError(
                f"no NN weights at {path}: train them first (see experiments/zumo_nn/README.md)"
            )
        try:
            with np.load(path, allow_pickle=False) as data:
                header = json.loads(str(data["header"]))
                n = int(header["n_layers"])
                return cls(
                    [data[f"W{i}"] for i in range(n)],
                    [data[f"b{i}"] for i in range(n)],
                    Activation(header["activation"]),
                    data["out_scale"],
                    data["out_offset"],
                    header.get("meta", {}),
                )
        except (ValueError, KeyError, EOFError, OSError, zipfile.BadZipFile) as exc:
            # not an npz (a pickle, text), cut short, or an npz of something else
            why = f"missing array {exc}" if isinstance(exc, KeyError) else str(exc) or repr(exc)
            why = why.split(". If you trust")[0]  # numpy's advice to unpickle: not for weights
            raise ConfigError(
                f"{path} is not an MLP weights file (.npz from mpclab.approx.train): {why}"
            ) from None
