"""NN export and forward pass: NumPy equals scikit-learn, C equals NumPy."""

from __future__ import annotations

import ctypes
import shutil
import subprocess
import warnings
from pathlib import Path

import numpy as np
import pytest

try:  # the `nn` extra; without it every test here is skipped (pytestmark)
    from sklearn.exceptions import ConvergenceWarning
    from sklearn.neural_network import MLPRegressor
except ImportError:
    pass

from mpclab.approx.export_c import time_compiled, to_c
from mpclab.policy.mlp import MLP

RNG = np.random.default_rng(3)

pytestmark = pytest.mark.needs("nn")


def fitted(hidden=(100,), activation="tanh", n_in=26, n_out=2) -> tuple[MLPRegressor, np.ndarray]:
    X = RNG.standard_normal((300, n_in))
    Y = np.tanh(X[:, :n_out] + 0.3 * X[:, n_out : 2 * n_out])
    model = MLPRegressor(
        hidden_layer_sizes=hidden, activation=activation, max_iter=50, random_state=0
    )
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ConvergenceWarning)  # a short fit is enough here
        model.fit(X, Y)
    return model, X


@pytest.mark.parametrize("hidden,activation", [((100,), "tanh"), ((32, 16), "relu")])
def test_numpy_forward_equals_sklearn_predict(hidden, activation) -> None:
    model, X = fitted(hidden, activation)
    mean, scale = X.mean(axis=0), X.std(axis=0)
    # train-time standardization is folded into the first layer
    model2 = MLPRegressor(
        hidden_layer_sizes=hidden, activation=activation, max_iter=50, random_state=0
    )
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ConvergenceWarning)
        model2.fit((X - mean) / scale, np.tanh(X[:, :2]))
    mlp = MLP.from_sklearn(model2, mean, scale, out_scale=[10.0, 10.0])
    Z = RNG.standard_normal((50, X.shape[1])) * 2
    expected = model2.predict((Z - mean) / scale) * 10.0
    np.testing.assert_allclose(mlp.forward(Z), expected, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(mlp.forward(Z[0]), expected[0], rtol=1e-12, atol=1e-12)


def test_save_and_load_round_trip(tmp_path: Path) -> None:
    model, X = fitted()
    mlp = MLP.from_sklearn(model, np.zeros(26), np.ones(26), [10, 10], meta={"features": "study"})
    loaded = MLP.load(mlp.save(tmp_path / "w.npz"))
    for a, b in zip(loaded.weights + loaded.biases, mlp.weights + mlp.biases, strict=True):
        np.testing.assert_array_equal(a, b)  # stored exactly
    # the same product on other memory may take another BLAS kernel: equal to rounding
    np.testing.assert_allclose(loaded.forward(X), mlp.forward(X), rtol=1e-13, atol=1e-13)
    assert loaded.meta == {"features": "study"} and loaded.sizes == [26, 100, 2]
    with pytest.raises(FileNotFoundError, match="train them first"):
        MLP.load(tmp_path / "missing.npz")


@pytest.mark.skipif(shutil.which("cc") is None, reason="no C compiler")
@pytest.mark.parametrize("hidden,activation", [((100,), "tanh"), ((32, 16), "relu")])
def test_exported_c_equals_numpy(tmp_path: Path, hidden, activation) -> None:
    model, X = fitted(hidden, activation)
    mlp = MLP.from_sklearn(model, X.mean(axis=0), X.std(axis=0), [10.0, 3.0], [0.5, -1.0])
    src = tmp_path / "nn.c"
    src.write_text(to_c(mlp, "zumo_nn"))
    text = src.read_text()
    assert "malloc" not in text and "#include <math.h>" in text
    lib = tmp_path / "libnn.so"
    subprocess.run(
        [
            "cc",
            "-std=c99",
            "-O2",
            "-Wall",
            "-Werror",
            "-shared",
            "-fPIC",
            str(src),
            "-o",
            str(lib),
            "-lm",
        ],
        check=True,
    )
    fn = ctypes.CDLL(str(lib)).zumo_nn
    dbl = ctypes.POINTER(ctypes.c_double)
    fn.argtypes, fn.restype = [dbl, dbl], None
    Z = RNG.standard_normal((100, 26)) * 3
    out = np.zeros(2)
    for z in Z:
        z = np.ascontiguousarray(z)
        fn(z.ctypes.data_as(dbl), out.ctypes.data_as(dbl))
        np.testing.assert_allclose(out, mlp.forward(z), rtol=0, atol=1e-6)
        np.testing.assert_allclose(out, mlp.forward(z), rtol=1e-12, atol=1e-12)


@pytest.mark.skipif(shutil.which("cc") is None and shutil.which("gcc") is None,
                    reason="no C compiler")
def test_timing_the_compiled_net_checks_its_outputs(monkeypatch: pytest.MonkeyPatch) -> None:
    model, X = fitted()
    mlp = MLP.from_sklearn(model, X.mean(axis=0), X.std(axis=0), [10.0, 3.0], [0.5, -1.0])
    rows = X[:7]
    t = time_compiled(mlp, rows, reps=3)
    assert t.shape == (21,) and np.all(t > 0) and np.all(t < 1.0)
    with pytest.raises(ValueError, match="rows have 25 features, the net takes 26"):
        time_compiled(mlp, rows[:, 1:], reps=1)
    # the check is real: a NumPy side that disagrees with the C is caught
    monkeypatch.setattr(MLP, "forward", lambda self, z: np.zeros((len(z), 2)))
    with pytest.raises(AssertionError, match="the compiled net and NumPy differ"):
        time_compiled(mlp, rows, reps=1)
