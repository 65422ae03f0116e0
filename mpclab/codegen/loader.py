"""Load a generated scheduled controller (:mod:`mpclab.codegen.scheduled`) into this process.

:class:`ScheduledLibrary` compiles the C with the machine's C compiler (cached by
:func:`mpclab.codegen.build.compile_shared`, the source and its header kept beside the
library) with the prediction tables in, loads it with
``ctypes`` and calls it on persistent buffers, so a step costs one foreign call and a few
copies.
"""

from __future__ import annotations

import ctypes
from collections.abc import Sequence
from enum import StrEnum
from pathlib import Path

import numpy as np
import numpy.typing as npt

from mpclab.codegen.build import compile_shared, kept_source
from mpclab.codegen.scheduled import ScheduledTables, scheduled_c, scheduled_h

FloatArray = npt.NDArray[np.float64]

#: the desktop build's flags: ISO C (no fused multiply-adds), optimized
DEFAULT_FLAGS = ("-O2", "-std=c99")


class Precision(StrEnum):
    """``mpc_real``: ``double``, or ``single`` (``float``, compiled with ``-DMPC_SINGLE``)."""

    double = "double"
    single = "single"


class ScheduledLibrary:
    """The generated controller of ``tables``, compiled in ``precision`` and loaded."""

    def __init__(self, tables: ScheduledTables, flags: Sequence[str] = DEFAULT_FLAGS,
                 precision: Precision = Precision.double) -> None:
        self.tables = tables
        self.precision = Precision(precision)
        self.source = scheduled_c(tables)
        single = ("-DMPC_SINGLE",) if self.precision is Precision.single else ()
        self.flags = (*flags, *single, "-DMPC_PREDICTION")
        self.path: Path = compile_shared(self.source, "scheduled", self.flags,
                                         header=scheduled_h(tables), keep_source=True)
        #: the generated C kept beside the library (the source, whole, and its header)
        self.generated: list[Path] = kept_source(self.path)
        lib = ctypes.CDLL(str(self.path))
        nx, nz, T = tables.nx, tables.nz, tables.horizon
        real = np.float32 if self.precision is Precision.single else np.float64
        self._x = np.zeros(nx, dtype=real)
        self._ref = np.zeros((T + 1) * nx, dtype=real)
        self._z = np.zeros(nz, dtype=real)
        self._X = np.zeros((T + 1) * nx, dtype=real)
        self._op, self._iters = ctypes.c_int(0), ctypes.c_int(0)
        self._step = lib.mpc_step
        self._step.restype = ctypes.c_int
        self._step.argtypes = [ctypes.c_void_p] * 3 + [ctypes.POINTER(ctypes.c_int)] * 2
        self._predict = lib.mpc_predict
        self._predict.restype = None
        self._predict.argtypes = [ctypes.c_int] + [ctypes.c_void_p] * 3
        self._px, self._pref, self._pz, self._pX = (
            ctypes.c_void_p(a.ctypes.data) for a in (self._x, self._ref, self._z, self._X)
        )
        self._pop, self._piters = ctypes.byref(self._op), ctypes.byref(self._iters)

    def step(self, x: FloatArray, ref: FloatArray) -> tuple[int, FloatArray, int, int]:
        """``(return code, z, op, iterations)`` of ``mpc_step`` at state ``x`` and the
        flattened reference ``ref``; ``z`` is a fresh array."""
        self._x[:] = x
        self._ref[:] = ref
        rc = self._step(self._px, self._pref, self._pz, self._pop, self._piters)
        return rc, self._z.astype(float), self._op.value, self._iters.value

    def predict(self, op: int, x: FloatArray, z: FloatArray) -> FloatArray:
        """The predicted states ``((T+1) nx,)`` of ``mpc_predict`` (a fresh array)."""
        self._x[:] = x
        self._z[:] = z
        self._predict(op, self._px, self._pz, self._pX)
        return self._X.astype(float)
