"""CasADi solver choices on the Zumo NLP: converged and in agreement with IPOPT, the compile
cache, status reading on real solvers, and the escape from the zero-input stationary point."""

from __future__ import annotations

import os
import warnings

import numpy as np
import pytest

from conftest import grouped
from mpclab.codegen import build as codegen_build
from mpclab.config.instantiate import build
from mpclab.constraints.obstacle import ObstacleDistance
from mpclab.controllers.base import SolveStatus, StepContext
from mpclab.controllers.casadi import compile as casadi_compile
from mpclab.controllers.casadi.mpc import CasadiMPC
from mpclab.controllers.casadi.ocp import Params
from mpclab.controllers.casadi.solvers import dotted
from mpclab.core.errors import ConfigError
from mpclab.objectives.base import Objective
from mpclab.objectives.potential import GoalAttraction
from mpclab.plants.zumo import Zumo
from mpclab.runner.single_run import compose

GOAL = np.array([1.6, 0.4, 0.0])
#: (state, detected points, active terms): BUG2's go-to-goal and wall-following sets, with
#: and without the input rate dU (which multiple shooting lifts into the stages: single
#: shooting does not, so the two agreeing checks the lifting)
STATES = [
    (np.array([0.4, 0.8, -1.2]), [[0.45, 0.65], [0.5, 0.62]], {"J1", "J2", "J3", "J4"}),
    (np.array([0.9, 0.7, 0.3]), [[1.1, 0.6 + 0.03 * i] for i in range(8)],
     {"J1", "J2", "J3", "J4", "dU"}),
    (np.array([1.0, 0.5, 1.4]), [[1.1, 0.4 + 0.03 * i] for i in range(12)],
     {"J3", "J4", "J5f", "dU"}),
]


@pytest.fixture(scope="module")
def zumo_setup():
    """The Zumo plant, BUG2's objective and controller config of the zumo_bug2 experiment."""
    cfg = compose(["+experiment=zumo_bug2_study", "controller=casadi"])
    plant = build(cfg.plant, "plant")
    return plant, cfg


def _mpc(zumo_setup, constraints=None, **kw) -> CasadiMPC:
    plant, cfg = zumo_setup
    objective = build(cfg.objective, "objective")
    if constraints:
        objective = Objective(objective.terms, constraints)
    return CasadiMPC(plant, objective, **grouped(CasadiMPC, horizon=10, dt=0.2, max_detections=20,
                     initial_input={"u1": 2.0, "u2": 2.0}, **kw))


def _ctx(det, active, goal=GOAL) -> StepContext:
    return StepContext(goal=goal, target=np.tile(goal, (11, 1)),
                       detections=np.array(det, dtype=float).reshape(-1, 2),
                       active=frozenset(active))


@pytest.mark.parametrize("opts", [
    {"solver": "fatrop"},
    {"solver": "ipopt", "shooting": "single"},
], ids=["fatrop", "ipopt-single"])
def test_solver_converges_and_agrees_with_ipopt(zumo_setup, opts) -> None:
    ref = _mpc(zumo_setup, solver="ipopt", tol=1e-8, max_iter=500)
    mpc = _mpc(zumo_setup, tol=1e-8, max_iter=500, **opts)
    for x, det, active in STATES:
        ref.reset(x)
        mpc.reset(x)
        a, b = ref.step(0.0, x, _ctx(det, active)), mpc.step(0.0, x, _ctx(det, active))
        assert a.status is SolveStatus.converged
        assert b.status is SolveStatus.converged, (x, b.solver_status)
        assert b.cost == pytest.approx(a.cost, rel=1e-4, abs=1e-6), x
        assert b.u == pytest.approx(a.u, abs=1e-3)


def test_fatrop_status_success_and_iteration_cap(zumo_setup) -> None:
    x, det, active = STATES[0]
    ok = _mpc(zumo_setup, solver="fatrop").step(0.0, x, _ctx(det, active))
    assert ok.status is SolveStatus.converged and ok.solver_status == "0"
    for x, det, active in STATES:  # a cap: truncated, applied, inside the input bounds
        for cap in (2, 3):
            res = _mpc(zumo_setup, solver="fatrop", max_iter=cap).step(0.0, x, _ctx(det, active))
            assert res.status is SolveStatus.truncated and not res.fallback, res.solver_status
            assert res.iterations is not None and res.iterations <= cap + 1
            assert np.all(np.abs(res.u_pred) <= 10.0)


def test_sqp_iteration_cap_is_truncated_never_converged(zumo_setup) -> None:
    x, det, active = STATES[0]
    res = _mpc(zumo_setup, solver="sqp_capped", qp_solver="qpoases", shooting="single",
               sqp_iterations=2).step(0.0, x, _ctx(det, active))
    assert res.status is SolveStatus.truncated and res.iterations == 2


def test_hpipm_on_single_shooting_is_refused(zumo_setup) -> None:
    with pytest.raises(ConfigError, match="hpipm"):
        _mpc(zumo_setup, solver="sqp", qp_solver="hpipm", shooting="single")
    with pytest.raises(ConfigError, match="fatrop"):
        _mpc(zumo_setup, solver="fatrop", shooting="single")


@pytest.mark.parametrize("opts", [
    {"solver": "fatrop"}, {"solver": "ipopt"},
    {"solver": "sqp", "qp_solver": "qrqp", "shooting": "single"},
], ids=["fatrop", "ipopt", "sqp-qrqp"])
def test_robot_at_rest_facing_sideways_to_its_goal_moves(zumo_setup, opts) -> None:
    # goal abeam (to the right of the heading): with goal attraction and input effort (J1,
    # J2) u = 0 is a stationary point of the NLP, where a zero guess stays
    x, goal = np.array([0.4, 0.8, 0.0]), np.array([0.4, 0.4, -np.pi / 2])
    ctx = _ctx(np.zeros((0, 2)), {"J1", "J2"}, goal)
    still = CasadiMPC(zumo_setup[0], build(zumo_setup[1].objective, "objective"),
                      **grouped(CasadiMPC, horizon=10, dt=0.2, **opts)).step(0.0, x, ctx)
    assert np.abs(still.u).max() < 1e-3
    res = _mpc(zumo_setup, **opts).step(0.0, x, ctx)  # initial_input's guess
    assert res.status is SolveStatus.converged
    assert np.abs(res.u).max() > 0.5 and res.cost < still.cost - 1.0
    assert np.hypot(*(res.x_pred[-1, :2] - goal[:2])) < 0.4 - 0.05  # nearer the goal


def test_a_zero_plan_or_fallback_is_not_a_warm_start(zumo_setup) -> None:
    mpc = _mpc(zumo_setup, solver="ipopt")
    x, det, active = STATES[0]
    mpc.step(0.0, x, _ctx(det, active))
    w, warm = mpc._initial_guess(x)
    assert warm
    mpc._plan.u_pred[:] = 0.0  # the previous plan was to stand still
    w, warm = mpc._initial_guess(x)
    assert not warm and w[mpc.ocp.u_idx] == pytest.approx(np.tile([2.0, 2.0], (10, 1)))


def test_params_pack_by_name() -> None:
    P = Params()
    P.add("a", 2)
    P.add("B", 2, 3)
    v = P.pack(a=[1, 2], B=np.arange(6).reshape(2, 3))
    assert v.tolist() == [1, 2, 0, 3, 1, 4, 2, 5]  # column-major, as ca.vec
    with pytest.raises(ValueError, match="missing"):
        P.pack(a=[1, 2])
    with pytest.raises(ValueError, match="shape"):
        P.pack(a=[1, 2, 3], B=np.zeros((2, 3)))


def _small(**kw) -> CasadiMPC:  # a small NLP: compiles in about a second at -O0
    plant = Zumo(input_bounds={"u1": [-10, 10], "u2": [-10, 10]})
    return CasadiMPC(plant, Objective({"J1": GoalAttraction()}), **grouped(
        CasadiMPC, horizon=3, dt=0.2, max_detections=0, initial_input={"u1": 2.0, "u2": 2.0},
        **kw))


def _no_source(write) -> str:
    raise AssertionError("the C source was written again")


def test_jit_compiles_once_and_then_hits_the_cache(tmp_path, monkeypatch) -> None:
    if codegen_build.find_compiler() is None:
        pytest.skip("no C compiler")
    monkeypatch.setenv("MPCLAB_CACHE", str(tmp_path))
    before = codegen_build.compile_count
    first = _small(solver="fatrop", jit=True, jit_flags=["-O0"])
    assert first.compiled and codegen_build.compile_count == before + 1
    (lib,) = tmp_path.glob("nlp_*.so")
    stamp = os.stat(lib).st_mtime_ns
    # found through the index of the problem's key: the C is not even written again
    with monkeypatch.context() as m:
        m.setattr(casadi_compile, "generated_c", _no_source)
        second = _small(solver="fatrop", jit=True, jit_flags=["-O0"])
    assert second.compiled and codegen_build.compile_count == before + 1  # no recompile
    assert os.stat(lib).st_mtime_ns == stamp
    assert sorted(p.suffix for p in tmp_path.iterdir()) == [".lib", ".so"]  # library, index
    lib.unlink()  # an index whose library is gone: compiled again
    assert _small(solver="fatrop", jit=True, jit_flags=["-O0"]).compiled
    assert codegen_build.compile_count == before + 2 and lib.is_file()
    # the compiled functions solve the same problem as the symbolic ones
    x, goal = np.array([0.4, 0.8, -1.2]), np.array([0.4, 0.4, 0.0])
    ctx = StepContext(goal=goal, target=np.tile(goal, (4, 1)))
    a = second.step(0.0, x, ctx)
    b = _small(solver="fatrop").step(0.0, x, ctx)
    assert a.status is b.status is SolveStatus.converged
    assert a.u_pred == pytest.approx(b.u_pred, abs=1e-6)


def test_jit_without_a_compiler_warns_and_runs_uncompiled(tmp_path, monkeypatch) -> None:
    monkeypatch.setenv("MPCLAB_CACHE", str(tmp_path))
    monkeypatch.setenv("CC", "no-such-c-compiler")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        mpc = _small(solver="fatrop", jit=True)
    assert not mpc.compiled and any("no C compiler" in str(w.message) for w in caught)
    x, goal = np.array([0.4, 0.8, -1.2]), np.array([0.4, 0.4, 0.0])
    res = mpc.step(0.0, x, StepContext(goal=goal, target=np.tile(goal, (4, 1))))
    assert res.status is SolveStatus.converged


@pytest.mark.parametrize("opts", [
    {"solver": "fatrop"},
    {"solver": "sqp", "qp_solver": "qrqp", "shooting": "multiple"},
    {"solver": "sqp", "qp_solver": "qrqp", "shooting": "single"},
], ids=["fatrop", "sqp-qrqp-multiple", "sqp-qrqp-single"])
def test_car_solvers_agree_with_ipopt(opts) -> None:
    cfg = compose(["+experiment=car_casadi"])
    plant, objective = build(cfg.plant, "plant"), build(cfg.objective, "objective")

    def mpc(**kw) -> CasadiMPC:
        return CasadiMPC(plant, objective, **grouped(
            CasadiMPC, horizon=10, dt=0.1, tol=1e-8, max_iter=500,
            terminal_constraint={"v": 0.0}, **kw))

    goal = np.zeros(plant.nx)
    ctx = StepContext(goal=goal, target=np.tile(goal, (11, 1)))
    ref, sol = mpc(solver="ipopt"), mpc(**opts)
    for x in ([-10.0, 10.0, 0.0, 0.0, 0.0], [-6.0, 4.0, -0.6, 5.0, 0.2]):
        x = np.array(x)
        a, b = ref.step(0.0, x, ctx), sol.step(0.0, x, ctx)
        assert a.status is b.status is SolveStatus.converged, b.solver_status
        assert b.cost == pytest.approx(a.cost, rel=1e-4)
        assert b.u == pytest.approx(a.u, abs=1e-3)


def test_fatrop_takes_the_collision_constraint_and_agrees_with_ipopt(zumo_setup) -> None:
    # the stage-wise constraint order lets fatrop detect the structure with path constraints
    x, det, active = STATES[0]
    kw = {"tol": 1e-8, "max_iter": 500}
    con = {"obstacles": ObstacleDistance(mode="hard", distance=0.06)}
    a = _mpc(zumo_setup, solver="ipopt", constraints=con, **kw).step(0.0, x, _ctx(det, active))
    b = _mpc(zumo_setup, solver="fatrop", constraints=con, **kw).step(0.0, x, _ctx(det, active))
    assert a.status is b.status is SolveStatus.converged
    assert b.cost == pytest.approx(a.cost, rel=1e-4)
    assert b.u == pytest.approx(a.u, abs=1e-3)
    points = np.array(det)
    dist = np.hypot(*(b.x_pred[1:, None, :2] - points[None]).transpose(2, 0, 1))
    assert dist.min() >= 0.06 - 1e-6


def test_one_nlp_per_active_set_solves_the_same_problem(zumo_setup) -> None:
    sets = [["J1", "J2", "J3", "J4"], ["J1", "J2", "J3", "J4", "dU"], ["J3", "J4", "J5f", "dU"]]
    full = _mpc(zumo_setup, solver="fatrop", tol=1e-8)
    split = _mpc(zumo_setup, solver="fatrop", tol=1e-8, active_sets=sets)
    assert len(split._by_set) == 3 and split.metrics(None)["nlps"] == 4
    for x, det, active in STATES:
        full.reset(x)
        split.reset(x)
        a, b = full.step(0.0, x, _ctx(det, active)), split.step(0.0, x, _ctx(det, active))
        assert split._nlp.names == [n for n in full._names if n in active]
        assert a.status is b.status is SolveStatus.converged
        assert b.cost == pytest.approx(a.cost, rel=1e-6)
        assert b.u_pred == pytest.approx(a.u_pred, abs=1e-5)
    with pytest.raises(ConfigError, match="active_sets"):
        _mpc(zumo_setup, solver="fatrop", active_sets=[["J1", "J9"]])


def test_nested_solver_options_reach_the_solver_as_casadis_dotted_names() -> None:
    assert dotted({"fatrop": {"max_iter": 1, "tol": 1e-3}, "print_time": False}) == {
        "fatrop.max_iter": 1, "fatrop.tol": 1e-3, "print_time": False}
    x, goal = np.array([0.4, 0.8, -1.2]), np.array([0.4, 0.4, 0.0])
    ctx = StepContext(goal=goal, target=np.tile(goal, (4, 1)))
    capped = _small(solver="fatrop", options={"fatrop": {"max_iter": 1}})
    assert capped.step(0.0, x, ctx).status is SolveStatus.truncated  # the cap took effect
