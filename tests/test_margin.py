"""The obstacle margin derived from stated bounds (mpclab.world.margin): each part against an
independent computation, the run record, the refusal of a layout with no room."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import ndimage

from conftest import compose_cfg
from mpclab.core.errors import ConfigError
from mpclab.plants.zumo import Zumo
from mpclab.runner.component_cache import ComponentCache
from mpclab.runner.single_run import build_run
from mpclab.world import margin
from mpclab.world.free_space import reachable

ZUMO = Zumo(input_bounds={"u1": [-10, 10], "u2": [-10, 10]})
X0 = np.zeros(3)
BASE = ["+experiment=zumo_bug2", "recorder=none", "progress=false"]
#: the narrow gap with no way around its walls: the gap (0.16 m between surfaces) only
CLOSED = ["scenario=zumo_narrow_gap", "scenario.layout.extent=[0.0,0.8,-0.1,1.3]"]


def _budget(overrides: list[str]) -> margin.MarginBudget:
    return build_run(compose_cfg([*BASE, *overrides])).margin


@pytest.mark.parametrize("radius", [0.015, 0.05])
def test_ray_part_bounds_random_cases(radius: float) -> None:
    """Random discs, ray angles and positions reached within one period's travel: wherever
    the position keeps R from the detected points, the true surface is no nearer than R
    minus the ray part (up to the grid's resolution), and the worst random case comes near
    the part (it is not inflated)."""
    R, n_rays, reach, travel = 0.065, 20, 0.3, 0.04
    part = margin.rays(R, [radius], n_rays, reach, travel)
    rng = np.random.default_rng(0)
    n = 40_000
    centre = rng.uniform(radius, reach + radius, n)
    offset = rng.uniform(0, 2 * math.pi / n_rays, n)
    r, a = travel * np.sqrt(rng.uniform(0, 1, n)), rng.uniform(0, 2 * math.pi, n)
    p = np.stack([r * np.cos(a), r * np.sin(a)], axis=1)
    ang = offset[:, None] + 2 * math.pi * np.arange(n_rays)[None] / n_rays
    b = centre[:, None] * np.cos(ang)
    disc = b**2 - (centre**2 - radius**2)[:, None]
    t = b - np.sqrt(np.maximum(disc, 0))
    hit = (disc >= 0) & (t >= 0) & (t <= reach)
    qx, qy = t * np.cos(ang), t * np.sin(ang)
    dq = np.where(hit, np.hypot(p[:, :1] - qx, p[:, 1:] - qy), np.inf).min(axis=1)
    true = np.hypot(p[:, 0] - centre, p[:, 1]) - radius
    seen = hit.any(axis=1) & (dq >= R)
    worst = float(np.max(R - true[seen]))
    assert worst <= part + 5e-4
    assert worst >= 0.6 * part


def test_between_samples_covers_the_path_against_every_point() -> None:
    """For each grid input's path over one period, brute force over points that both ends
    keep R from: no point comes nearer the path than R minus the part."""
    R, dt = 0.065, 0.2
    travel, moves = margin.motion(ZUMO, X0, dt)
    part = margin.between_samples(R, moves)
    assert travel == pytest.approx(0.2 * dt, rel=1e-6)  # top speed r * u_max = 0.2 m/s
    # the straight move at top speed: R - sqrt(R^2 - (c/2)^2), no bow
    assert part >= R - math.sqrt(R**2 - (travel / 2) ** 2) - 1e-12
    g = np.linspace(-0.11, 0.11, 881)  # 0.25 mm
    qx, qy = np.meshgrid(g, g)
    q = np.stack([qx.ravel(), qy.ravel()], axis=1)
    worst = 0.0
    for u in margin._input_grid(ZUMO):
        path = margin._path(ZUMO, X0, u, dt)
        keep = (np.hypot(*(q - path[0]).T) >= R) & (np.hypot(*(q - path[-1]).T) >= R)
        d = np.min(np.hypot(q[keep, None, 0] - path[None, :, 0],
                            q[keep, None, 1] - path[None, :, 1]), axis=1)
        worst = max(worst, float(np.max(R - d)))
    assert worst <= part + 1e-9
    assert worst >= 0.8 * part


def test_latency_part_is_the_top_speed_reversal() -> None:
    """An uncompensated latency tau: the previous input can drive backwards at top speed
    while the model assumes forwards, 2 v_max tau apart; the corners of the input bounds
    find that."""
    world = build_run(compose_cfg([*BASE, "sim.latency=30"])).world
    part, missing = margin.latency(world, ZUMO, X0, 0.2)
    assert missing is None
    assert part == pytest.approx(2 * 0.2 * 0.030, rel=0.02)


def test_summary_parts_and_sim_noise_change_the_margin(run_cfg) -> None:
    ideal = _budget([])
    realistic = _budget(["sim=realistic"])
    noisier = _budget(["sim=realistic", "sim.noise.range_std=0.01"])
    assert ideal.noise == 0 and ideal.latency == 0
    assert realistic.noise > 0 and realistic.latency > 0
    assert ideal.total < realistic.total < noisier.total
    assert realistic.estimate == 0  # points and robot placed from the same estimate
    result, _ = run_cfg([*BASE, "scenario.t_max=1.0"])
    parts = result.summary["margin"]
    assert parts["total_m"] == pytest.approx(ideal.total, rel=1e-9)
    assert set(parts) >= {f"{p}_m" for p in margin.MarginBudget.PARTS}
    info = result.summary["constraints"]["obstacles"] if "constraints" in result.summary \
        else None
    if info is not None:
        assert info["distance_m"] == pytest.approx(ideal.total, rel=1e-9)


def test_a_margin_with_no_room_is_refused_with_its_parts() -> None:
    assert _budget(CLOSED).total < 0.08  # the ideal loop passes the 0.16 m gap
    with pytest.raises(ConfigError, match=r"latency 0\.06.*no way from the start.*no_room=run"):
        _budget([*CLOSED, "sim.latency=150"])
    run = build_run(compose_cfg([*BASE, *CLOSED, "sim.latency=150",
                                 "objective.constraints.obstacles.no_room=run"]))
    assert run.no_room and "no way" in run.no_room
    stated = build_run(compose_cfg([*BASE, *CLOSED, "sim.latency=150",
                                    "objective.constraints.obstacles.distance=0.07"]))
    assert stated.controller.objective.constraints["obstacles"].distance == pytest.approx(0.07)
    with pytest.raises(ConfigError, match="sim.noise.confidence"):
        _budget(["sim.noise.confidence=1.5"])


def test_cache_keeps_controllers_apart_by_margin() -> None:
    """A warm worker reuses a controller only for the same margin (it is built into the
    problem)."""
    cache = ComponentCache()
    a = build_run(compose_cfg(BASE), cache=cache)
    b = build_run(compose_cfg([*BASE, "sim.noise.range_std=0.005"]), cache=cache)
    c = build_run(compose_cfg([*BASE, "seed=1"]), cache=cache)
    assert a.controller is not b.controller and a.controller is c.controller
    assert a.plant is b.plant is c.plant
    assert b.controller.objective.constraints["obstacles"].distance > \
        a.controller.objective.constraints["obstacles"].distance


def test_bug2_path_runs_outside_a_larger_margin() -> None:
    """BUG2's path along a boundary keeps its stated clearance where the margin allows, and
    runs ``outside_margin`` outside the margin where that comes nearer; the gap it treats as
    closed (``run_link``) stays twice the stated clearance."""
    ideal = build_run(compose_cfg(BASE)).supervisor
    assert ideal.clearance == pytest.approx(0.08) and ideal.run_link == pytest.approx(0.16)
    run = build_run(compose_cfg([*BASE, "scenario=zumo_random", "sim=realistic"]))
    R = run.margin.total
    assert R > 0.08 - 0.015
    assert run.supervisor.clearance == pytest.approx(R + 0.015)
    assert run.supervisor.least_clearance == pytest.approx(R + 0.005)
    assert run.supervisor.run_link == pytest.approx(0.16)


def test_the_record_says_what_distance_was_kept(run_cfg) -> None:
    derived, _ = run_cfg([*BASE, "scenario.t_max=0.4"], name="derived")
    stated, _ = run_cfg([*BASE, "scenario.t_max=0.4",
                         "objective.constraints.obstacles.distance=0.065"], name="stated")
    d, s = derived.summary["margin"], stated.summary["margin"]
    assert d["kept_m"] == pytest.approx(d["total_m"]) and not d["stated"]
    assert s["kept_m"] == pytest.approx(0.065) and s["stated"]
    assert s["total_m"] == pytest.approx(d["total_m"])  # still derived, to compare


def test_reachable_cells_equal_scipys_labelling() -> None:
    """The room check's flood fill (runs filled along rows, then columns) against scipy's
    connected-component labelling, on 300 random grids."""
    rng = np.random.default_rng(0)
    for _ in range(300):
        n, m = rng.integers(1, 40, 2)
        free = rng.random((n, m)) < rng.uniform(0.3, 0.9)
        seeds = rng.random((n, m)) < 0.03
        labels, _ = ndimage.label(free)
        want = free & np.isin(labels, np.unique(labels[seeds & free]))
        assert np.array_equal(reachable(free, seeds), want)
