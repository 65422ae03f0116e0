"""A planar range sensor: rays from the robot's centre, exact ray-disc intersections.

Ray ``j`` points at ``theta + offset + 2 pi j / n_rays``; it reports the distance to the
first disc surface it meets within ``max_range`` (``inf`` when it meets none). Every ray is
intersected with every disc at once (arrays ``(n_rays, n_discs)``), no loop over either.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from mpclab.core.errors import ConfigError, number

FloatArray = npt.NDArray[np.float64]


@dataclass
class SensorConf:
    n_rays: int = 20            # rays evenly spread over 360 degrees
    max_range: float = 0.3      # [m]
    offset_deg: float = 0.0     # angle of ray 0 from the heading [deg]


def ray_disc_distances(
    origin: npt.ArrayLike, angles: npt.ArrayLike, discs: npt.ArrayLike
) -> FloatArray:
    """Distance along each ray to the first intersection with any disc.

    Parameters
    ----------
    origin
        Ray origin ``(2,)`` [m].
    angles
        Ray directions ``(n,)`` [rad].
    discs
        ``(m, 3)``: centre x, centre y, radius [m].

    Returns
    -------
    Distances ``(n,)`` [m]; ``inf`` where a ray meets no disc ahead of the origin. A tangent
    ray hits at its touching point; an origin inside a disc gives 0 for every ray.
    """
    o = np.asarray(origin, dtype=float).reshape(2)
    a = np.asarray(angles, dtype=float).reshape(-1)
    discs = np.asarray(discs, dtype=float).reshape(-1, 3)
    if discs.shape[0] == 0:
        return np.full(a.shape, np.inf)
    d = np.stack([np.cos(a), np.sin(a)], axis=1)           # (n, 2) unit directions
    rel = discs[:, :2] - o                                  # (m, 2) centres from origin
    b = d @ rel.T                                           # (n, m) projection on the ray
    c = np.sum(rel**2, axis=1) - discs[:, 2] ** 2           # (m,) > 0 outside the disc
    disc = b**2 - c[None, :]
    with np.errstate(invalid="ignore"):
        t = b - np.sqrt(disc)                               # first crossing of the circle
    hit = (disc >= 0) & (t >= 0)
    t = np.where(hit, t, np.inf)
    t = np.where((c <= 0)[None, :], 0.0, t)                 # inside a disc: blind at 0
    return t.min(axis=1)


class RangeSensor:
    """``n_rays`` rays over 360 degrees around the robot, each seeing up to ``max_range``.

    Parameters
    ----------
    n_rays
        Number of rays (the study: 20, 18 degrees apart).
    max_range
        Detection range [m].
    offset_deg
        Angle of the first ray from the robot's heading [deg].
    """

    def __init__(self, n_rays: int = 20, max_range: float = 0.3, offset_deg: float = 0.0) -> None:
        if int(n_rays) < 1:
            raise ConfigError(f"scenario.sensor.n_rays must be >= 1, got {n_rays}")
        self.n_rays = int(n_rays)
        self.max_range = number(max_range, "scenario.sensor.max_range", above=0)
        offset = number(offset_deg, "scenario.sensor.offset_deg")
        self._rel = np.deg2rad(offset) + 2 * np.pi * np.arange(self.n_rays) / self.n_rays

    def angles(self, theta: float) -> FloatArray:
        """World angles of the rays for heading ``theta`` ``(n_rays,)`` [rad]."""
        return float(theta) + self._rel

    def distances(self, pose: npt.ArrayLike, discs: npt.ArrayLike) -> FloatArray:
        """Range per ray ``(n_rays,)`` from ``pose = (x, y, theta)``; ``inf`` beyond range."""
        x, y, theta = (float(v) for v in np.asarray(pose, dtype=float)[:3])
        dist = ray_disc_distances((x, y), self.angles(theta), discs)
        return np.where(dist <= self.max_range, dist, np.inf)

    def points(self, pose: npt.ArrayLike, ranges: npt.ArrayLike) -> FloatArray:
        """Ray end points ``(n_rays, 2)`` of a reading: the hit point, or the point at max range."""
        x, y, theta = (float(v) for v in np.asarray(pose, dtype=float)[:3])
        ranges = np.asarray(ranges, dtype=float)
        reach = np.where(np.isfinite(ranges), ranges, self.max_range)
        ang = self.angles(theta)
        return np.stack([x + reach * np.cos(ang), y + reach * np.sin(ang)], axis=1)

    def end_points(
        self, pose: npt.ArrayLike, discs: npt.ArrayLike
    ) -> tuple[FloatArray, FloatArray]:
        """Ray end points ``(n_rays, 2)`` (hit point or the point at max range) and hit mask."""
        dist = self.distances(pose, discs)
        return self.points(pose, dist), np.isfinite(dist)

    def detect(self, pose: npt.ArrayLike, discs: npt.ArrayLike) -> FloatArray:
        """Detected points ``(l, 2)``: the hit points of the rays that hit, in ray order."""
        pts, hit = self.end_points(pose, discs)
        return pts[hit]
