"""A generated scheduled controller's time per step on the F401RE, from one PIL trace.

The controller's C is cross-built and run on QEMU over calibration states; the cycle model
(:mod:`mpclab.codegen.cycles`, its central timing) weighs every traced step. The time per step
is then a line in the active-set iterations of that step::

    cycles(iterations) = base + per_iteration * iterations

``per_iteration`` is the least-squares slope over the traced steps (0 when they all took as
many iterations, e.g. the closed form of control horizon 1, which counts none), ``base`` the
largest ``cycles - per_iteration * iterations`` among them: the line lies on or above every
traced step. The fit is kept as JSON in the compile cache (``$MPCLAB_CACHE``, named by a hash
of the C source, the precision, the cross compiler's version and flags, the calibration
states and the model's version), so a controller's trace is paid once on a machine.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import subprocess
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt

from mpclab.codegen import cycles, pil
from mpclab.codegen.build import cache_dir
from mpclab.codegen.loader import Precision, ScheduledLibrary

FloatArray = npt.NDArray[np.float64]

#: bump when the cycle model or the fit changes (old cached fits are then not used)
MODEL_VERSION = "1"
#: the longest the calibration's emulated run may take [s]
TIMEOUT_S = 3600.0
#: the active set's iteration cap (box_qp.c's MPC_QP_MAX_ITERATIONS)
ITERATION_CAP = 200


@dataclass(frozen=True)
class StepModel:
    """Modelled cycles of one controller's step on the F401RE, by active-set iterations."""

    precision: str
    base: float  # cycles
    per_iteration: float  # cycles per active-set iteration
    samples: int  # traced calibration steps
    iterations_traced: tuple[int, int]  # the fewest and the most iterations traced
    residual_max: float  # the largest distance of a traced step below the line [cycles]
    instructions_max: int  # the most instructions of a traced step
    cycles_max: float  # the most modelled cycles of a traced step
    timing: str = "central"
    clock_hz: float = pil.F401RE_CLOCK_HZ

    def cycles(self, iterations: int) -> float:
        return self.base + self.per_iteration * max(int(iterations), 0)

    def seconds(self, iterations: int) -> float:
        return self.cycles(iterations) / self.clock_hz

    def describe(self) -> str:
        return (f"cycle model ({self.timing}) of a PIL trace of {self.samples} steps, "
                f"{self.precision} precision: {self.base:.0f} + {self.per_iteration:.0f} x "
                f"active-set iterations cycles at {self.clock_hz / 1e6:g} MHz")


def fit(iterations: npt.ArrayLike, cycles_: npt.ArrayLike) -> tuple[float, float, float]:
    """``(base, per_iteration, residual_max)``: the least-squares slope, moved up to lie on or
    above every point; ``residual_max`` how far the line lies above the lowest-lying point."""
    it = np.asarray(iterations, dtype=float)
    c = np.asarray(cycles_, dtype=float)
    slope = float(np.polyfit(it, c, 1)[0]) if np.ptp(it) > 0 else 0.0
    slope = max(slope, 0.0)
    rest = c - slope * it
    return float(rest.max()), slope, float(rest.max() - rest.min())


def _toolchain() -> str:
    out = subprocess.run(["arm-none-eabi-gcc", "--version"], check=True, capture_output=True,
                         text=True).stdout
    return out.splitlines()[0]


def _key(library: ScheduledLibrary, precision: Precision, x: FloatArray,
         ref: FloatArray) -> str:
    parts = [library.source, str(precision), _toolchain(), *pil.CM4_FLAGS, *pil.BUILD_FLAGS,
             repr(dataclasses.astuple(cycles.CENTRAL)), MODEL_VERSION]
    h = hashlib.sha256("\n".join(parts).encode())
    h.update(np.ascontiguousarray(x, dtype=float).tobytes())
    h.update(np.ascontiguousarray(ref, dtype=float).tobytes())
    return h.hexdigest()[:24]


def step_model(library: ScheduledLibrary, x: FloatArray, ref: FloatArray,
               precision: Precision) -> StepModel:
    """The step model of ``library``'s C in ``precision``, traced on the states ``x (n, nx)``
    and references ``ref (n, nref)`` (cached on disk)."""
    missing = pil.missing_tools()
    if missing:
        raise RuntimeError(f"the Cortex-M4 step model needs {', '.join(missing)} (Debian: "
                           "apt-get install gcc-arm-none-eabi libnewlib-arm-none-eabi "
                           "qemu-system-arm)")
    file = cache_dir() / "m4_step_model" / f"{_key(library, precision, x, ref)}.json"
    if file.is_file():
        data = json.loads(file.read_text())
        data["iterations_traced"] = tuple(data["iterations_traced"])
        return StepModel(**data)
    with tempfile.TemporaryDirectory(prefix="mpclab_m4_") as tmp:
        try:
            elf, _ = pil.cross_build(pil.harness_source(library.source, x, ref), precision,
                                     Path(tmp))
        except subprocess.CalledProcessError as exc:  # e.g. more than the F401RE's flash
            raise RuntimeError(f"the {precision} cross build failed: "
                               f"{(exc.stderr or '').strip()[-400:]}") from None
        steps = pil.run(elf, count_instructions=True, timeout_s=TIMEOUT_S,
                        timings={"central": cycles.CENTRAL})
    its = [s.iterations for s in steps]
    cyc = [s.cycles["central"] for s in steps]
    base, slope, spread = fit(its, cyc)
    model = StepModel(str(precision), base, slope, len(steps), (min(its), max(its)), spread,
                      max(s.instructions or 0 for s in steps), max(cyc))
    file.parent.mkdir(parents=True, exist_ok=True)
    part = file.with_suffix(f".{os.getpid()}.tmp")  # whole files only: parallel workers
    part.write_text(json.dumps(dataclasses.asdict(model)))
    part.replace(file)
    return model
