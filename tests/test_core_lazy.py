"""Heavy optional dependencies load when first used: a CasADi run never imports CVXPY."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from mpclab.core.lazy_import import lazy_import

ROOT = Path(__file__).resolve().parents[1]


def test_lazy_module_runs_on_first_attribute_access(tmp_path: Path, monkeypatch) -> None:
    (tmp_path / "mpclab_lazy_probe.py").write_text(
        "import builtins\n"
        "builtins.mpclab_probe_loads = getattr(builtins, 'mpclab_probe_loads', 0) + 1\n"
        "VALUE = 42\n"
    )
    monkeypatch.syspath_prepend(str(tmp_path))
    import builtins

    monkeypatch.delitem(sys.modules, "mpclab_lazy_probe", raising=False)
    mod = lazy_import("mpclab_lazy_probe")
    assert getattr(builtins, "mpclab_probe_loads", 0) == 0  # not executed yet
    assert mod.VALUE == 42
    assert builtins.mpclab_probe_loads == 1
    assert lazy_import("mpclab_lazy_probe") is mod  # loaded: the same module
    monkeypatch.delattr(builtins, "mpclab_probe_loads")
    monkeypatch.delitem(sys.modules, "mpclab_lazy_probe")


def test_unknown_module_is_an_import_error() -> None:
    with pytest.raises(ModuleNotFoundError, match="no_such_module_xyz"):
        lazy_import("no_such_module_xyz")


def test_a_casadi_run_imports_neither_cvxpy_nor_the_training_app() -> None:
    # nor scipy.stats or .special (the tables' interval is exact binomial tails), nor pyplot
    # without figures, nor mpclab.approx and scikit-learn (composing walks only the
    # component packages)
    code = (
        "import sys\n"
        "from mpclab.runner.single_run import build_run, compose\n"
        "from mpclab.runner.loop import simulate\n"
        "run = build_run(compose(['+experiment=zumo_bug2', 'recorder=none', '+ci=smoke']))\n"
        "simulate(run)\n"
        "print(sorted(m for m in ('cvxpy.atoms', 'scipy.stats', 'scipy.special', 'clarabel',\n"
        "    'sklearn', 'mpclab.approx', 'matplotlib.pyplot') if m in sys.modules))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True,
                         check=True)
    assert out.stdout.strip().splitlines()[-1] == "[]"


def test_the_direct_path_status_words_are_cvxpys() -> None:
    import cvxpy as cp

    from mpclab.controllers.cvxpy import direct as cvxpy_direct

    assert set(cvxpy_direct._STATUS.values()) == {
        cp.OPTIMAL, cp.OPTIMAL_INACCURATE, cp.INFEASIBLE, cp.INFEASIBLE_INACCURATE,
        cp.UNBOUNDED, cp.UNBOUNDED_INACCURATE, cp.USER_LIMIT,
    }
    assert cvxpy_direct._SOLVER_ERROR == cp.SOLVER_ERROR
