"""Where a run's data lives in a Rerun recording, and the blueprints that lay it out.

Every recording (``run.rrd``) uses the entity paths below; :mod:`mpclab.recorders.merge`
puts each run of a sweep under its own prefix (``/<run>/world/...``). Timelines: ``step``
(controller call, a sequence) and ``sim_time`` (simulated time, a duration).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # rerun is imported only when a recording is made (it is slow to import)
    import rerun.blueprint as rrb

#: timelines every temporal entity is logged on
STEP, SIM_TIME = "step", "sim_time"

WORLD = "world"  # static Transform3D flipping y: 2D views draw y downwards, the map y upwards
OBSTACLES = "world/obstacles"  # static Points2D: centres, radii = obstacle radii
GOAL = "world/goal"  # static Arrows2D (Points2D without a heading)
START = "world/start"  # static Arrows2D (Points2D without a heading)
MLINE = "world/mline"  # static LineStrips2D: BUG2's m-line
REFERENCE_PATH = "world/reference"  # static LineStrips2D: a tracking reference's path
VEHICLE = "world/vehicle"  # per step Arrows2D (Points2D without a heading)
PATH = "world/path"  # per step LineStrips2D: one segment from the last position to this one
MEASURED = "world/measured"  # per step Points2D: the measured position (sim with state noise)
HORIZON = "world/horizon"  # per step LineStrips2D: the predicted positions, horizon + 1 points
RAYS = "world/rays"  # per step LineStrips2D: one segment per sensor ray
DETECTIONS = "world/detections"  # per step Points2D: detected obstacle points
STATES = "series/states"  # /<label>: Scalars; /<label>/reference: the reference
INPUTS = "series/inputs"  # /<label>: Scalars
SOLVER = "series/solver"  # /solve_time_ms, /quality (SOLVE_QUALITY), /cost
SOLVE_TIME = f"{SOLVER}/solve_time_ms"
SOLVE_QUALITY = f"{SOLVER}/quality"
COST = f"{SOLVER}/cost"
LATENCY = f"{SOLVER}/latency_ms"  # when the input acted after the measurement (sim latency)
MODE_LOG = "log/mode"  # TextLog: supervisor mode, on each change
SOLVER_LOG = "log/solver"  # TextLog: solver status, on each change
RUN_LOG = "log/run"  # TextLog: how the run ended
CONFIG = "run/config"  # static TextDocument: resolved config and package versions


def _history() -> rrb.VisibleTimeRanges:
    """Everything from the start up to the time cursor, on both timelines."""
    import rerun.blueprint as rrb

    return rrb.VisibleTimeRanges(
        [
            rrb.VisibleTimeRange(
                timeline,
                start=rrb.TimeRangeBoundary.infinite(),
                end=rrb.TimeRangeBoundary.cursor_relative(),
            )
            for timeline in (STEP, SIM_TIME)
        ]
    )


def map_view(
    prefix: str = "", name: str = "map", bounds: Sequence[float] | None = None
) -> rrb.Spatial2DView:
    """The 2D map: world, vehicle, horizon; the path accumulates up to the time cursor.

    ``bounds``: ``(x_min, x_max, y_min, y_max)`` [m] shown at first (None: fit the data).
    """
    import rerun.blueprint as rrb

    visual = None
    if bounds is not None:
        x0, x1, y0, y1 = map(float, bounds)
        # the view's space is /world's parent, where y is flipped
        visual = rrb.VisualBounds2D(x_range=[x0, x1], y_range=[-y1, -y0])
    return rrb.Spatial2DView(
        origin=prefix or "/",  # the space above /world, so that world's y flip applies
        contents=f"{prefix}/{WORLD}/**",
        name=name,
        overrides={f"{prefix}/{PATH}": _history(), f"{prefix}/{MEASURED}": _history()},
        visual_bounds=visual,
    )


def series_views(
    states: Sequence[str], inputs: Sequence[str], prefixes: Sequence[str] = ("",)
) -> list[rrb.TimeSeriesView]:
    """One time-series panel per key state, per input and for the solve time.

    With several ``prefixes`` (a merged sweep) each panel overlays that signal of every run.
    """
    import rerun.blueprint as rrb

    views = [
        rrb.TimeSeriesView(name=label, origin="/", contents=[f"{p}/{STATES}/{label}/**"
                                                             for p in prefixes])
        for label in states
    ]
    views += [
        rrb.TimeSeriesView(name=label, origin="/", contents=[f"{p}/{INPUTS}/{label}"
                                                             for p in prefixes])
        for label in inputs
    ]
    views.append(rrb.TimeSeriesView(name="solve time, latency [ms]", origin="/",
                                    contents=[c for p in prefixes
                                              for c in (f"{p}/{SOLVE_TIME}", f"{p}/{LATENCY}")]))
    views.append(rrb.TimeSeriesView(name="solve: converged 2, truncated 1, fell back 0",
                                    origin="/",
                                    contents=[f"{p}/{SOLVE_QUALITY}" for p in prefixes]))
    return views


def run_blueprint(
    states: Sequence[str], inputs: Sequence[str], bounds: Sequence[float] | None = None
) -> rrb.Blueprint:
    """A single run: the map beside stacked time series, events and the config in tabs."""
    import rerun.blueprint as rrb

    return rrb.Blueprint(
        rrb.Horizontal(
            map_view(bounds=bounds),
            rrb.Vertical(
                *series_views(states, inputs),
                rrb.Tabs(
                    rrb.TextLogView(origin="/log", name="events"),
                    rrb.TextDocumentView(origin=f"/{CONFIG}", name="config"),
                ),
            ),
            column_shares=[3, 2],
        ),
        collapse_panels=True,
    )


def sweep_blueprint(
    prefixes: Sequence[str], states: Sequence[str], inputs: Sequence[str],
    bounds: Sequence[float] | None = None,
) -> rrb.Blueprint:
    """A merged sweep: one map per run side by side above time series overlaying the runs."""
    import rerun.blueprint as rrb

    maps = [map_view(f"/{p}", name=p, bounds=bounds) for p in prefixes]
    return rrb.Blueprint(
        rrb.Vertical(
            rrb.Grid(*maps) if len(maps) > 1 else maps[0],
            rrb.Grid(*series_views(states, inputs, [f"/{p}" for p in prefixes]), grid_columns=4),
            rrb.TextLogView(origin="/", contents=[f"/{p}/log/**" for p in prefixes],
                            name="events"),
            row_shares=[3, 2, 1],
        ),
        collapse_panels=True,
    )
