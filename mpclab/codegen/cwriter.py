"""Numbers and arrays as C text: every value with 17 significant digits (a double's round
trip), infinities as ``INFINITY`` (``<math.h>``)."""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt


def c_number(v: float) -> str:
    """``v`` as a C literal that reads back as the same double."""
    if math.isinf(v):
        return "INFINITY" if v > 0 else "-INFINITY"
    if math.isnan(v):
        raise ValueError("NaN has no place in a generated table")
    return f"{v:.17g}"


def c_values(a: npt.ArrayLike) -> str:
    """A (nested) brace initializer of the array ``a``."""
    a = np.asarray(a)
    if a.ndim == 1:
        return "{" + ", ".join(c_number(float(v)) for v in a) + "}"
    return "{\n    " + ",\n    ".join(c_values(row) for row in a) + "}"


def c_array(name: str, a: npt.ArrayLike, ctype: str = "double") -> str:
    """``static const CTYPE NAME[d0][d1]... = {...};`` for the array ``a``."""
    a = np.asarray(a, dtype=float)
    dims = "".join(f"[{d}]" for d in a.shape)
    return f"static const {ctype} {name}{dims} = {c_values(a)};"


def c_int_array(name: str, values: list[int], ctype: str = "int") -> str:
    """``static const CTYPE NAME[n] = {...};`` for whole numbers."""
    return f"static const {ctype} {name}[{len(values)}] = {{{', '.join(map(str, values))}}};"
