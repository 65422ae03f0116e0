"""Figure files that say what they show.

:func:`save_figure` writes a matplotlib figure as PNG with, in a text chunk of the file, what
its panels show: per axes the title, the axis labels, the legend entries (and whether the
legend lies over the panel) and how many data artists it drew. :func:`read_figure` reads
that back with the image's size and how much of it is not background, so a test (or a
user's script) checks a figure without looking at it.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from mpclab.core.lazy_import import pyplot

#: the PNG text chunk that holds the description
CHUNK = "mpclab:figure"


@dataclass(frozen=True)
class Panel:
    """What one axes of a figure shows."""

    title: str
    xlabel: str
    ylabel: str
    legend: tuple[str, ...]
    artists: int  # lines, collections, patches and images with data
    legend_inside: bool  # the legend's box overlaps the panel's (it may cover data)


@dataclass(frozen=True)
class FigureFile:
    """A figure read back: pixels, the share that is not background, and its panels."""

    width: int
    height: int
    ink: float  # share of pixels that differ from the corner's colour
    panels: tuple[Panel, ...]
    legend: tuple[str, ...]  # the figure's own legend (outside the panels)

    @property
    def labels(self) -> set[str]:
        """Every legend entry of the figure and its panels."""
        return set(self.legend).union(*(p.legend for p in self.panels))


def describe(fig: Any) -> dict[str, Any]:
    """What ``fig``'s panels show (see the module docstring), as plain data."""
    fig.draw_without_rendering()  # places the legends
    renderer = fig.canvas.get_renderer()
    panels = []
    for ax in fig.axes:
        if not ax.get_visible() or ax.get_label() == "<colorbar>":
            continue
        legend = ax.get_legend()
        panels.append({
            "title": ax.get_title() or ax.get_title(loc="left"),
            "xlabel": ax.get_xlabel(), "ylabel": ax.get_ylabel(),
            "legend": [t.get_text() for t in legend.get_texts()] if legend else [],
            "artists": sum(_has_data(a) for a in
                           (*ax.lines, *ax.collections, *ax.patches, *ax.images)),
            "legend_inside": bool(legend and legend.get_window_extent(renderer).overlaps(
                ax.get_window_extent(renderer))),
        })
    legend = [t.get_text() for lg in fig.legends for t in lg.get_texts()]
    return {"panels": panels, "legend": legend}


def _has_data(artist: Any) -> bool:
    """Whether ``artist`` draws any data (an empty proxy drawn for a legend entry does not)."""
    for get in ("get_xydata", "get_segments", "get_offsets", "get_array"):
        if hasattr(artist, get):  # a line, a line collection, a scatter, an image
            data = getattr(artist, get)()
            return data is not None and len(data) > 0
    return True  # a patch


def save_figure(fig: Any, path: Path, dpi: int = 110) -> Path:
    """Write ``fig`` as PNG to ``path`` (cropped to what is drawn, legends outside the panels
    included) with its :func:`describe` in the file; the figure is closed."""
    path = Path(path)
    fig.savefig(path, dpi=dpi, bbox_inches="tight", pad_inches=0.1,
                metadata={CHUNK: json.dumps(describe(fig))})
    pyplot().close(fig)
    return path


def read_figure(path: Path) -> FigureFile:
    """The PNG at ``path`` with what :func:`save_figure` wrote into it."""
    from PIL import Image  # matplotlib's own dependency, needed only to read figures back

    with Image.open(path) as img:
        text = dict(getattr(img, "text", {}))
        rgb = np.asarray(img.convert("RGB"), dtype=np.int16)
    background = rgb[0, 0]
    ink = float(np.mean(np.any(np.abs(rgb - background) > 8, axis=2)))
    info = json.loads(text.get(CHUNK, '{"panels": [], "legend": []}'))
    panels = tuple(Panel(p["title"], p["xlabel"], p["ylabel"], tuple(p["legend"]), p["artists"],
                         p["legend_inside"]) for p in info["panels"])
    return FigureFile(rgb.shape[1], rgb.shape[0], ink, panels, tuple(info["legend"]))
