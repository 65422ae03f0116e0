"""Feature vectors the NN controller sees: the study's 26, or a better-conditioned set.

``study``: ``[x, y, theta, x0, y0, theta0, 1/d_1, ..., 1/d_n]`` with ``1/inf = 0`` (a ray that
sees nothing), as in Study B.

``body``: the goal in the robot's body frame ``(dx_b, dy_b)``, its distance, ``sin`` and
``cos`` of the heading error ``theta0 - theta``, and the clipped inverse ranges
``min(1, d_min / d_i)`` (0 for a ray that sees nothing): every entry is bounded, none depends
on where the world's origin is, and angles do not jump at +-pi.
"""

from __future__ import annotations

from enum import StrEnum

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]


class FeatureSet(StrEnum):
    study = "study"
    body = "body"


def n_features(kind: FeatureSet | str, n_rays: int) -> int:
    return {FeatureSet.study: 6, FeatureSet.body: 5}[FeatureSet(kind)] + int(n_rays)


def features(
    kind: FeatureSet | str,
    pose: npt.ArrayLike,
    goal: npt.ArrayLike,
    ranges: npt.ArrayLike,
    min_range: float = 0.05,
) -> FloatArray:
    """Feature rows for a batch.

    Parameters
    ----------
    kind
        ``study`` or ``body``.
    pose
        Robot poses ``(N, 3)`` or ``(3,)``: x, y, theta.
    goal
        Goal pose ``(3,)`` or ``(N, 3)``: x0, y0, theta0.
    ranges
        Ray ranges ``(N, n_rays)`` or ``(n_rays,)`` [m], ``inf`` where nothing is seen.
    min_range
        ``d_min`` of the ``body`` set's clipped inverse ranges [m].

    Returns
    -------
    ``(N, n_features)`` (or ``(n_features,)`` for a single pose).
    """
    pose = np.asarray(pose, dtype=float)
    single = pose.ndim == 1
    P = np.atleast_2d(pose)
    G = np.broadcast_to(np.asarray(goal, dtype=float), P.shape)
    D = np.atleast_2d(np.asarray(ranges, dtype=float))
    if D.shape[0] != P.shape[0]:
        raise ValueError(f"ranges has {D.shape[0]} rows for {P.shape[0]} poses")
    with np.errstate(divide="ignore"):
        inv = np.where(np.isfinite(D), 1.0 / D, 0.0)
    kind = FeatureSet(kind)
    if kind is FeatureSet.study:
        out = np.concatenate([P, G, inv], axis=1)
    else:
        th = P[:, 2]
        dx, dy = G[:, 0] - P[:, 0], G[:, 1] - P[:, 1]
        c, s = np.cos(th), np.sin(th)
        err = G[:, 2] - th
        out = np.column_stack([
            c * dx + s * dy, -s * dx + c * dy, np.hypot(dx, dy), np.sin(err), np.cos(err),
            np.minimum(1.0, float(min_range) * inv),
        ])
    return out[0] if single else out
