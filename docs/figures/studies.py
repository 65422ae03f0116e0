"""The scenario figures of docs/studies.md, drawn from the repository's own configs.

From the repository root::

    uv run python docs/figures/studies.py

writes, into ``docs/figures/``:

* ``study_a_scenario.png``: Study A, the car's start pose, goal and stop region
  (``+experiment=car_cvxpy``, scenario ``car_to_origin``);
* ``study_b_layouts.png``: Study B, the layouts of the study's Fig. 4, Fig. 5/6 and Fig. 7/8
  (scenarios ``zumo_one_obstacle``, ``zumo_wall``, ``zumo_dead_end``) with the range sensor's
  rays at the start;
* ``study_b_right_hand.png``: Study B, the right-hand rule's attracting points ``g_i`` (J5) for
  a robot facing the wide wall;
* ``study_c_scenarios.png``: Study C, the reference paths of ``control_y_V``,
  ``regular_circle_turn`` and ``turn`` with the operating-point switches along them, and
  ``control_y_V``'s references over time.

Every scene is composed with ``mpclab.compose`` and its plant and scenario are built as a run
builds them: obstacles, sensor rays, detected points and references come from mpclab's own
code. No controller is built and nothing is simulated.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.patches import Circle, FancyArrowPatch, Polygon  # noqa: E402

import mpclab  # noqa: E402
from mpclab.config.instantiate import build  # noqa: E402
from mpclab.record.figure_file import save_figure  # noqa: E402

HERE = Path(__file__).resolve().parent

START, GOAL = "tab:red", "tab:blue"   # the study's colours: red start, blue goal
RAYS, HITS, PULL = "tab:orange", "tab:orange", "tab:green"


def scene(overrides: list[str]) -> tuple[Any, Any, Any]:
    """The composed config, its plant and its scenario (seed 0: no random layout is used)."""
    cfg = mpclab.compose(overrides)
    plant = build(cfg.plant, "plant")
    scenario = build(cfg.scenario, "scenario", plant=plant,
                     rng=np.random.default_rng(int(cfg.seed)))
    return cfg, plant, scenario


def arrival_radius(scenario: Any) -> float:
    """Radius of the arrival region in the position plane (unit weights on x and y; the
    car's rule also weighs v, so this is its region at rest)."""
    return float(np.sqrt(scenario.arrival_threshold))


def heading_arrow(ax: Any, x: float, y: float, theta: float, length: float,
                  color: str, **kw: Any) -> None:
    ax.add_patch(FancyArrowPatch((x, y), (x + length * np.cos(theta),
                                          y + length * np.sin(theta)),
                                 arrowstyle="-|>", mutation_scale=12, color=color, lw=1.5,
                                 zorder=5, **kw))


# ------------------------------------------------------------------------------ Study A
def study_a() -> Path:
    cfg, plant, sc = scene(["+experiment=car_cvxpy"])
    ix, iy, ith = (plant.state_index(s) for s in ("px", "py", "theta"))
    x0, g = sc.x0, sc.goal
    fig, ax = plt.subplots(figsize=(5.2, 4.8))
    # the car at the start: a 1.6 m x 0.8 m body around its wheelbase, heading theta
    l_wb = float(cfg.plant.params.l)
    c, s = np.cos(x0[ith]), np.sin(x0[ith])
    body = np.array([[-0.3, -0.4], [l_wb + 0.3, -0.4], [l_wb + 0.3, 0.4], [-0.3, 0.4]])
    rot = np.array([[c, -s], [s, c]])
    ax.add_patch(Polygon(body @ rot.T + x0[[ix, iy]], closed=True, color=START, alpha=0.8,
                         label=f"start ({x0[ix]:g}, {x0[iy]:g}), heading +x, at rest"))
    heading_arrow(ax, x0[ix] + l_wb + 0.3, x0[iy], x0[ith], 1.5, START)
    ax.add_patch(Circle((g[ix], g[iy]), arrival_radius(sc), fill=False, ls=":", color=GOAL,
                        label=r"stop: $p_x^2 + p_y^2 + v^2 < 1$ (circle: $v = 0$)"))
    ax.plot(g[ix], g[iy], "o", color=GOAL, label="goal: the origin")
    ax.plot([x0[ix], g[ix]], [x0[iy], g[iy]], "--", color="0.5", lw=0.8,
            label=f"straight line, {np.hypot(x0[ix] - g[ix], x0[iy] - g[iy]):.1f} m")
    ax.set_xlim(-12.0, 2.5)
    ax.set_ylim(-2.0, 12.5)
    ax.set_aspect("equal")
    ax.grid(True, alpha=0.3)
    ax.set_xlabel("px [m]")
    ax.set_ylabel("py [m]")
    ax.set_title("Study A: scenario car_to_origin")
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.13), ncol=1, fontsize=8,
              frameon=False)
    return save_figure(fig, HERE / "study_a_scenario.png")


# ------------------------------------------------------------------------------ Study B
ZUMO_LAYOUTS = (
    ("zumo_potential", "zumo_one_obstacle", "Fig. 4: one obstacle"),
    ("zumo_right_hand", "zumo_wall", "Fig. 5/6: wide wall"),
    ("zumo_bug2", "zumo_dead_end", "Fig. 7/8: dead end"),
)


def draw_zumo(ax: Any, sc: Any, plant: Any, pose: np.ndarray, legend: bool,
              robot: str = "start") -> None:
    """Obstacles, m-line, goal, the robot at ``pose`` with its sensor's rays and hits."""
    ip = [plant.state_index(s) for s in plant.position]
    ih = plant.state_index(plant.heading)
    start, goal = sc.x0[ip], sc.goal[ip]
    sc.draw(ax)
    ax.plot(*np.transpose([start, goal]), "--", color="0.45", lw=0.9,
            label="m-line (start to goal)" if legend else None)
    ends = sc.rays(pose)
    hits = sc.detect(pose)
    p = pose[ip]
    for k, e in enumerate(ends):
        ax.plot([p[0], e[0]], [p[1], e[1]], "-", color=RAYS, lw=0.6, alpha=0.7,
                label=f"{sc.sensor.n_rays} rays, {sc.sensor.max_range:g} m"
                if (legend and k == 0) else None)
    if len(hits):
        ax.plot(hits[:, 0], hits[:, 1], "x", color=HITS, ms=5, mew=1.4,
                label="detected points $(x_i, y_i)$" if legend else None)
    ax.add_patch(Circle(p, sc.robot_radius, fill=False, color=START, lw=1.5,
                        label=f"robot (disc r = {sc.robot_radius:g} m), {robot}" if legend
                        else None, zorder=4))
    heading_arrow(ax, p[0], p[1], pose[ih], 0.09, START)
    ax.add_patch(Circle(goal, arrival_radius(sc), fill=False, ls=":", color=GOAL, lw=1.2,
                        label=f"arrival: within {100 * arrival_radius(sc):.0f} cm" if legend
                        else None))
    ax.plot(*goal, "o", color=GOAL, ms=5, label="goal, heading +x" if legend else None)
    heading_arrow(ax, goal[0], goal[1], sc.goal[ih], 0.09, GOAL)
    ax.set_aspect("equal")
    ax.grid(True, alpha=0.3)
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")


def study_b_layouts() -> Path:
    fig, axes = plt.subplots(1, 3, figsize=(13.0, 4.6), sharey=True, layout="constrained")
    for k, (ax, (exp, name, title)) in enumerate(zip(axes, ZUMO_LAYOUTS, strict=True)):
        cfg, plant, sc = scene([f"+experiment={exp}", f"scenario={name}"])
        draw_zumo(ax, sc, plant, sc.x0, legend=k == 0)
        ax.set_xlim(-0.12, 0.92)
        ax.set_ylim(0.28, 1.14)
        ax.set_title(f"{title}\nscenario={name}", fontsize=10)
        if k:
            ax.set_ylabel("")
    fig.legend(*axes[0].get_legend_handles_labels(), loc="outside lower center", ncol=4,
               frameon=False, fontsize=9)
    fig.suptitle("Study B: the study's layouts as mpclab builds them (obstacle discs r = 0.05 m)")
    return save_figure(fig, HERE / "study_b_layouts.png")


def study_b_right_hand() -> Path:
    cfg, plant, sc = scene(["+experiment=zumo_right_hand", "scenario=zumo_wall"])
    j5 = cfg.objective.terms.J5
    ip = [plant.state_index(s) for s in plant.position]
    ih = plant.state_index(plant.heading)
    # the robot facing the wall (toward its goal), its body 5 cm from the discs' surfaces
    wall_y = float(cfg.scenario.layout.walls[0].start[1])
    pose = sc.x0.copy()
    pose[ip[1]] = wall_y + float(cfg.scenario.layout.obstacle_radius) + sc.robot_radius + 0.05
    pose[ih] = -np.pi / 2
    fig, ax = plt.subplots(figsize=(6.6, 5.0))
    draw_zumo(ax, sc, plant, pose, legend=True, robot="facing the wall")
    p = pose[ip]
    a = np.deg2rad(float(j5.angle_deg))
    rot = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    hits = sc.detect(pose)
    pulls = (hits - p) @ rot.T + p
    for h in hits:  # the rotation of each detected point: an arc about the robot
        rho, phi = np.hypot(*(h - p)), np.arctan2(*(h - p)[::-1])
        arc = phi + np.linspace(0.0, a, 30)
        ax.plot(p[0] + rho * np.cos(arc), p[1] + rho * np.sin(arc), "-", color=PULL, lw=0.8,
                alpha=0.8)
    ax.plot(pulls[:, 0], pulls[:, 1], "o", color=PULL, ms=5,
            label=rf"$g_i$: $(x_i, y_i)$ turned {float(j5.angle_deg):g}° CCW about the robot")
    ax.set_xlim(-0.05, 0.85)
    ax.set_ylim(0.35, 1.0)
    ax.set_title(f"Study B, J5 (right-hand rule): C4 = {float(j5.C4):g}, "
                 f"L4 = {float(j5.L4):g} m\nthe robot faces the wall of scenario=zumo_wall",
                 fontsize=10)
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.12), ncol=2, fontsize=8,
              frameon=False)
    return save_figure(fig, HERE / "study_b_right_hand.png")


# ------------------------------------------------------------------------------ Study C
BICYCLE = (
    ("control_y_V", "control_y_V: lane change of 2 m, speed 1 to 2 m/s"),
    ("regular_circle_turn", "regular_circle_turn: R = 8 m, one lap + 45°"),
    ("turn", "turn: 5 m, 90° left on R = 8 m, 10 m"),
)


def nearest(values: np.ndarray, grid: list[float], periodic: bool) -> np.ndarray:
    """Index of the nearest grid value (on the circle when ``periodic``)."""
    d = values[:, None] - np.asarray(grid)[None, :]
    if periodic:
        d = np.arctan2(np.sin(d), np.cos(d))
    return np.argmin(np.abs(d), axis=1)


def reference(sc: Any) -> Any:
    """The scenario's reference table from 0 to ``t_end`` (the run arrives near its end)."""
    ref = sc.reference_table()
    return ref[ref["t"] <= sc.t_end + 1e-9]


def draw_path(ax: Any, cfg: Any, sc: Any, title: str) -> None:
    ref = reference(sc)
    start = cfg.scenario.start
    ax.plot(ref["px"], ref["py"], "--", color="k", lw=1.0, label="reference path")
    ax.plot(float(start.px), float(start.py), "o", color=START, ms=6, label="start")
    heading_arrow(ax, float(start.px), float(start.py), float(start.theta), 2.0, START)
    end = sc.goal
    ax.plot(end[sc.plant.state_index("px")], end[sc.plant.state_index("py")], "s",
            color=GOAL, ms=6, label="end of the reference, t_end (arrival: within 0.5 m)")
    if "theta" in ref:
        ops = [float(v) for v in cfg.controller.schedule.operating_points.theta]
        idx = nearest(ref["theta"].to_numpy(), ops, periodic=True)
        sw = np.flatnonzero(np.diff(idx)) + 1
        ax.plot(ref["px"].to_numpy()[sw], ref["py"].to_numpy()[sw], "D", color="tab:purple",
                ms=6, label=r"nearest heading point changes ($\theta = \pi/4 + k\pi/2$)")
    ax.set_aspect("equal")
    ax.grid(True, alpha=0.3)
    ax.set_xlabel("px [m]")
    ax.set_ylabel("py [m]")
    ax.set_title(title, fontsize=10)


def study_c() -> Path:
    fig = plt.figure(figsize=(12.0, 8.6))
    gs = fig.add_gridspec(2, 2, height_ratios=[1.0, 1.5])
    axes = [fig.add_subplot(gs[0, 0]), fig.add_subplot(gs[0, 1]),
            fig.add_subplot(gs[1, 0]), fig.add_subplot(gs[1, 1])]
    handles: dict[str, Any] = {}
    for ax, (name, title) in zip([axes[0], axes[2], axes[3]], BICYCLE, strict=True):
        cfg, plant, sc = scene(["+experiment=bicycle_scheduled", f"scenario={name}"])
        draw_path(ax, cfg, sc, title)
        for h, lab in zip(*ax.get_legend_handles_labels(), strict=True):
            handles.setdefault(lab, h)
        if name == "control_y_V":
            ax.set_ylim(-2.0, 4.0)
            ref = reference(sc)
            tax = axes[1]
            tax.plot(ref["t"], ref["py"], "-", color="tab:blue", label="py reference [m]")
            tax.plot(ref["t"], ref["V"], "-", color="tab:red", label="V reference [m/s]")
            vs = [float(v) for v in cfg.controller.schedule.operating_points.V]
            tax.axhline(0.5 * (vs[0] + vs[1]), color="tab:red", ls=":", lw=0.9,
                        label=f"V = {0.5 * (vs[0] + vs[1]):g} m/s: nearest speed point changes")
            tax.set_xlabel("t [s]")
            tax.set_ylabel("py [m], V [m/s]")
            tax.set_ylim(-0.2, 2.5)
            tax.grid(True, alpha=0.3)
            tax.set_title("control_y_V: references over time (theta not referenced)",
                          fontsize=10)
            tax.legend(loc="lower right", fontsize=8)
    fig.legend(handles.values(), handles.keys(), loc="lower center", ncol=2,
               bbox_to_anchor=(0.5, -0.05), frameon=False, fontsize=9)
    fig.suptitle("Study C: the scenarios as mpclab defines them (operating points: "
                 "theta in {0, pi/2, pi, -pi/2} x V in {1, 2} m/s)", y=0.99)
    fig.tight_layout(rect=(0, 0.02, 1, 0.97))
    return save_figure(fig, HERE / "study_c_scenarios.png")


def main() -> None:
    for draw in (study_a, study_b_layouts, study_b_right_hand, study_c):
        print(draw())


if __name__ == "__main__":
    main()
