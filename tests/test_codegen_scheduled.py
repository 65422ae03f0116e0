"""The scheduled controller's generated C (SIL): the same steps as its Python twin.

The C is emitted from the matrices the Python controller precomputed and compiled with the
machine's C compiler; both solve the same box QP by the same method (closed form for 2
variables, the active-set method otherwise), so they differ by floating-point summation order
only. Stated tolerance: 1e-9 on the inputs (rad, m/s^2) and predicted states, every step of a
whole closed-loop run; operating point and status identical.
"""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest
from test_bicycle import controller, ctx, random_target

from mpclab.codegen import build as codegen_build
from mpclab.codegen.loader import DEFAULT_FLAGS
from mpclab.codegen.scheduled import QpMethod
from mpclab.controllers.base import SolveStatus
from mpclab.controllers.scheduled.generated_c import ScheduledSIL
from mpclab.core.errors import ConfigError
from mpclab.record import files as record

pytestmark = pytest.mark.skipif(codegen_build.find_compiler() is None, reason="no C compiler")

TOL = 1e-9


def _random_state(rng: np.random.Generator) -> np.ndarray:
    return np.array([rng.normal(0, 3), rng.normal(0, 3), rng.uniform(-7, 7),
                     rng.normal(0, 0.3), rng.normal(0, 0.05), rng.uniform(0.3, 2.8)])


@pytest.mark.parametrize(("horizon", "control_horizon", "solver"),
                         [(32, 1, "auto"), (16, 1, "auto"), (32, 4, "auto"),
                          (16, 8, "auto"), (16, 1, "active_set")])
def test_generated_c_steps_as_the_python_controller(horizon, control_horizon, solver) -> None:
    """Random states and previews, every heading turn and both speeds: same op, same moves
    (many at a bound), same prediction."""
    rng = np.random.default_rng(3)
    kw = dict(horizon=horizon, control_horizon=control_horizon, solver=solver)
    py, c = controller(**kw), controller(codegen=True, **kw)
    ops, at_bound = set(), 0
    for _ in range(150):
        x = _random_state(rng)
        ref = random_target(rng, x, horizon)
        a, b = py.step(0.0, x, ctx(ref)), c.step(0.0, x, ctx(ref))
        assert b.status is SolveStatus.converged and not b.fallback
        assert b.info["op"] == a.info["op"]
        np.testing.assert_allclose(b.u_pred, a.u_pred, rtol=0, atol=TOL)
        np.testing.assert_allclose(b.x_pred, a.x_pred, rtol=0, atol=TOL * 100)
        assert b.cost == pytest.approx(a.cost, rel=1e-9)
        ops.add(a.info["op"])
        at_bound += int(np.any(np.isclose(np.abs(a.u), [np.radians(30), 2.0])))
    assert ops == set(range(8)) and at_bound > 10  # every point, and the bounds are active


@pytest.mark.slow
@pytest.mark.parametrize("control_horizon", [1, 4])
def test_sil_whole_run_agrees_with_the_python_twin(run_cfg, control_horizon) -> None:
    """A whole closed loop through every heading, once in Python and once from generated C."""
    base = ["+experiment=bicycle_scheduled", "scenario=regular_circle_turn",
            f"controller.control_horizon={control_horizon}"]
    _, py_dir = run_cfg(base, name="python")
    _, c_dir = run_cfg([*base, "controller.codegen=true"], name="c")
    summaries = [json.loads((d / "summary.json").read_text()) for d in (py_dir, c_dir)]
    assert [s["codegen"] for s in summaries] == [False, True]
    assert summaries[1]["converged_fraction"] == 1.0 and summaries[1]["status"] == "arrived"
    a, b = (record.controller_steps(pd.read_parquet(d / "steps.parquet"))
            for d in (py_dir, c_dir))
    assert len(a) == len(b) and (a["op"] == b["op"]).all() and a["op"].nunique() >= 4
    np.testing.assert_allclose(b[["delta", "a"]], a[["delta", "a"]], rtol=0, atol=TOL)


#: single against double C in the closed loop: float rounds every table entry and operation
#: (relative 6e-8) and the runs drift apart by as much; inputs of order 1 (rad, m/s^2)
SINGLE_TOL = 1e-3


@pytest.mark.slow
@pytest.mark.parametrize("control_horizon", [1, 4])
def test_single_precision_c_drives_the_whole_run_as_the_double(run_cfg, control_horizon) -> None:
    """The float build of the same C in the loop (controller.codegen_precision=single): the
    same arrival and operating points, every step converged, the inputs within SINGLE_TOL of
    the double build's at every step and the same tracking RMS (to 1e-4 relative)."""
    base = ["+experiment=bicycle_scheduled", "scenario=regular_circle_turn",
            "controller.codegen=true", f"controller.control_horizon={control_horizon}"]
    _, d_dir = run_cfg(base, name="double")
    _, s_dir = run_cfg([*base, "controller.codegen_precision=single"], name="single")
    d, s = (json.loads((p / "summary.json").read_text()) for p in (d_dir, s_dir))
    assert (d["codegen_precision"], s["codegen_precision"]) == ("double", "single")
    assert s["status"] == d["status"] == "arrived"
    assert s["arrival_time_s"] == d["arrival_time_s"] and s["converged_fraction"] == 1.0
    assert s["rms_position"] == pytest.approx(d["rms_position"], rel=1e-4)
    a, b = (record.controller_steps(pd.read_parquet(p / "steps.parquet")) for p in (d_dir, s_dir))
    assert len(a) == len(b) and (a["op"] == b["op"]).all()
    du = np.abs(b[["delta", "a"]].to_numpy() - a[["delta", "a"]].to_numpy())
    assert 0 < du.max() <= SINGLE_TOL  # float, not double, and close to it


def test_codegen_refuses_what_it_cannot_generate() -> None:
    with pytest.raises(ConfigError, match="mode=switched"):
        controller(schedule={"mode": "interpolated"}, codegen=True)
    with pytest.raises(ConfigError, match="hysteresis"):
        controller(schedule={"hysteresis": {"theta": 0.1}}, codegen=True)
    with pytest.raises(ConfigError, match="CVXPY"):
        controller(solver="OSQP", codegen=True)


def test_the_compiled_controller_is_cached(tmp_path, monkeypatch) -> None:
    monkeypatch.setenv("MPCLAB_CACHE", str(tmp_path))
    before = codegen_build.compile_count
    controller(horizon=8, codegen=True)
    controller(horizon=8, codegen=True)
    assert codegen_build.compile_count == before + 1
    assert len(list(tmp_path.glob("scheduled_*.so"))) == 1
    controller(horizon=9, codegen=True)  # other matrices: another source, another library
    assert len(list(tmp_path.glob("scheduled_*.so"))) == 2


def test_a_capped_active_set_is_reported_truncated_not_converged() -> None:
    """With the iteration cap at 1, steps that need more passes say so."""
    c = controller(control_horizon=4, codegen=True)
    capped = ScheduledSIL(c, QpMethod.active_set, (*DEFAULT_FLAGS, "-DMPC_QP_MAX_ITERATIONS=1"))
    rng = np.random.default_rng(5)
    seen = set()
    for _ in range(60):
        x = _random_state(rng)
        ref = random_target(rng, x).ravel()
        _, _, _, full_status, _, iters = c._sil.step(x, ref)
        _, _, _, status, word, _ = capped.step(x, ref)
        assert full_status is SolveStatus.converged
        if iters > 1:
            assert (status, word) == (SolveStatus.truncated, "max_iterations")
        else:
            assert status is SolveStatus.converged
        seen.add(status)
    assert seen == {SolveStatus.converged, SolveStatus.truncated}
