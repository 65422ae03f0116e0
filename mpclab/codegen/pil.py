"""Processor in the loop on an emulated Cortex-M4F: cross build, footprint, run, instruction count.

The generated controller's C (the very source the desktop build compiles) is cross-compiled
with Debian's ``gcc-arm-none-eabi`` for the STM32F401RE's core (``-mcpu=cortex-m4
-mfpu=fpv4-sp-d16 -mfloat-abi=hard``), in double precision (the FPU is single precision only:
doubles run in software, libgcc's ``__aeabi_d*``) or single (``-DMPC_SINGLE``), and linked
against the F401RE's memory (512 KB flash, 96 KB SRAM: a build that does not fit fails to
link). A bare-metal harness (``pil/``) runs it on recorded states under ``qemu-system-arm -M
netduinoplus2`` (an STM32F405, Cortex-M4F) and prints each step's result through semihosting.

Executed instructions are counted exactly: with ``-singlestep -d exec,nochain`` QEMU logs one
line per executed instruction, named by its function; the lines between ``pil_begin`` and
``pil_end`` are the step's. QEMU does not model the core's timing: the cycles of a step are
the executed addresses weighed by the Cortex-M4 cycle model (:mod:`mpclab.codegen.cycles`;
``timings``), and its time those cycles at the F401RE's 84 MHz.
"""

from __future__ import annotations

import shutil
import subprocess
import tempfile
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import numpy.typing as npt
import pandas as pd

from mpclab.codegen import cycles
from mpclab.codegen.cwriter import c_array
from mpclab.codegen.loader import Precision, ScheduledLibrary
from mpclab.record import files as record

FloatArray = npt.NDArray[np.float64]

HARNESS = Path(__file__).with_name("pil")
#: the STM32F401RE's core and FPU (single-precision FPv4, hard-float calling convention)
CM4_FLAGS = ("-mcpu=cortex-m4", "-mthumb", "-mfpu=fpv4-sp-d16", "-mfloat-abi=hard")
#: the cross build's other flags: ISO C (no fused multiply-adds), optimized, unused code dropped
BUILD_FLAGS = ("-O2", "-std=c99", "-ffunction-sections", "-fdata-sections")
#: the F401RE's memory [bytes] and clock [Hz]
F401RE_FLASH, F401RE_RAM, F401RE_CLOCK_HZ = 512 * 1024, 96 * 1024, 84e6
TOOLS = ("arm-none-eabi-gcc", "arm-none-eabi-size", "qemu-system-arm")
QEMU_BOARD = "netduinoplus2"


@dataclass(frozen=True)
class Footprint:
    """Sizes of a linked firmware [bytes] (``arm-none-eabi-size``) and the step's stack."""

    text: int
    data: int
    bss: int
    stack: int

    @property
    def flash(self) -> int:
        return self.text + self.data

    @property
    def ram(self) -> int:
        return self.data + self.bss + self.stack


@dataclass(frozen=True)
class PilStep:
    """One step on the emulated board: ``mpc_step``'s results and its instruction count."""

    op: int
    code: int
    iterations: int
    z: FloatArray
    instructions: int | None
    #: modelled cycles by timing name (:mod:`mpclab.codegen.cycles`; empty: not asked)
    cycles: dict[str, float] = field(default_factory=dict)


def missing_tools() -> list[str]:
    """The cross-build and emulation tools not on the path (empty when PIL can run)."""
    return [t for t in TOOLS if shutil.which(t) is None]


def harness_source(controller_c: str, x: FloatArray, ref: FloatArray,
                   main_c: str | None = None) -> str:
    """The firmware's C: the controller, the recorded states ``x (n, nx)``, ``ref (n, nref)``
    (as doubles; cast to ``mpc_real`` on the board) and a ``main`` (the PIL harness's unless
    ``main_c`` is given)."""
    x, ref = np.atleast_2d(x), np.atleast_2d(ref)
    return "\n".join([
        controller_c, f"#define PIL_N {x.shape[0]}", c_array("pil_x", x), c_array("pil_ref", ref),
        (HARNESS / "main.c").read_text() if main_c is None else main_c,
    ])


def cross_build(source: str, precision: Precision, folder: Path,
                extra_flags: Sequence[str] = ()) -> tuple[Path, Footprint]:
    """Compile and link ``source`` for the Cortex-M4F; the ELF and its footprint (the stack of
    ``main``'s call chain from GCC's ``-fstack-usage``, summed over the harness's frames)."""
    folder.mkdir(parents=True, exist_ok=True)
    c = folder / "firmware.c"
    c.write_text(source)
    elf = folder / "firmware.elf"
    defs = ["-DMPC_SINGLE"] if precision is Precision.single else []
    cmd = ["arm-none-eabi-gcc", *CM4_FLAGS, *BUILD_FLAGS, *defs, *extra_flags, "-fstack-usage",
           "-nostartfiles", "--specs=nano.specs", "-T", str(HARNESS / "f401re.ld"),
           "-Wl,--gc-sections", str(HARNESS / "startup.c"), str(c), "-lm", "-o", str(elf)]
    subprocess.run(cmd, check=True, capture_output=True, text=True, cwd=folder)
    out = subprocess.run(["arm-none-eabi-size", str(elf)], check=True, capture_output=True,
                         text=True).stdout.splitlines()[1].split()
    su = next(folder.glob("*firmware.su"))  # GCC names it after the output (and the source)
    return elf, Footprint(int(out[0]), int(out[1]), int(out[2]), _stack(su))


def _stack(su: Path) -> int:
    """Bytes of stack of the deepest frames: main plus the controller's call chain (an upper
    bound: the frames of every ``mpc_*`` function, as if all were live at once)."""
    total = 0
    for line in su.read_text().splitlines():
        name, size = line.split("\t")[0].rsplit(":", 1)[-1], int(line.split("\t")[1])
        if name == "main" or name.startswith("mpc_"):
            total += size
    return total


def run(elf: Path, count_instructions: bool, timeout_s: float = 120.0,
        timings: Mapping[str, cycles.Timing] | None = None) -> list[PilStep]:
    """Run the firmware under QEMU; per step its printed result and (if asked) instructions
    and the modelled cycles under each of ``timings`` (:mod:`mpclab.codegen.cycles`; the
    caches warm from step to step)."""
    with tempfile.TemporaryDirectory(prefix="mpclab_pil_") as tmp:
        log, console = Path(tmp) / "exec.log", Path(tmp) / "console.txt"
        cmd = ["qemu-system-arm", "-M", QEMU_BOARD, "-display", "none", "-monitor", "none",
               "-serial", "null", "-chardev", f"file,id=semihosting,path={console}",
               "-semihosting-config", "enable=on,target=native,chardev=semihosting",
               "-kernel", str(elf)]
        if count_instructions or timings:
            cmd += ["-singlestep", "-d", "exec,nochain", "-D", str(log)]
        subprocess.run(cmd, check=True, capture_output=True, stdin=subprocess.DEVNULL,
                       timeout=timeout_s)
        out = console.read_text()
        windows = step_windows(log) if count_instructions or timings else None
    lines = out.splitlines()
    if not lines or lines[-1].strip() != "done":
        raise RuntimeError(f"the PIL firmware did not finish: {out[-300:]!r}")
    modelled: list[dict[str, float]] = [{} for _ in lines[:-1]]
    if timings and windows is not None:
        program = cycles.Program.of(elf)
        for name, timing in timings.items():
            machine = cycles.Machine.cold()
            if windows:  # warm: as the previous step of a control loop left the caches
                cycles.step_cycles(program, *windows[0], timing, machine)
            for i, (pcs, nxt) in enumerate(windows):
                modelled[i][name] = cycles.step_cycles(program, pcs, nxt, timing, machine)
    steps = []
    for i, line in enumerate(lines[:-1]):
        op, code, iters, *z = line.split()
        dtype = np.float64 if len(z[0]) == 16 else np.float32
        zs = np.array([int(v, 16) for v in z], dtype=np.uint64 if dtype is np.float64
                      else np.uint32).view(dtype).astype(float)
        steps.append(PilStep(int(op, 16), int(code, 16), int(iters, 16), zs,
                             None if windows is None else len(windows[i][0]) - 1,
                             modelled[i]))
    return steps


def step_windows(log: Path) -> list[tuple[npt.NDArray[np.int64], int]]:
    """Per step of an exec log, the executed addresses from ``pil_begin``'s return up to the
    call of ``pil_end`` and the address after the last (that call). Its instruction count
    is one less (an instruction of the marker's call the compiler places in the window)."""
    windows, pcs = [], None
    with log.open() as f:
        for line in f:
            if line.endswith("] pil_begin\n"):
                pcs = []
            elif line.endswith("] pil_end\n") and pcs is not None:
                windows.append((np.array(pcs[:-1], dtype=np.int64), pcs[-1]))
                pcs = None
            elif pcs is not None:
                i = line.index("/")
                pcs.append(int(line[i + 1:i + 9], 16))
    return windows


@dataclass(frozen=True)
class PilCheck:
    """A controller on the emulated board beside the desktop build of the same C.

    ``footprint`` is the firmware with one recorded state (what a board with the controller
    alone would hold, plus the harness's buffers of one state and reference); ``steps`` are
    the board's results on every recorded state; ``desktop`` the desktop C's ``(op, z)``.
    """

    precision: Precision
    footprint: Footprint
    steps: list[PilStep]
    desktop: list[tuple[int, FloatArray]]

    @property
    def ops_agree(self) -> bool:
        return all(s.op == op for s, (op, _) in zip(self.steps, self.desktop, strict=True))

    @property
    def max_input_difference(self) -> float:
        """The largest ``|z_board - z_desktop|`` over steps and moves."""
        return max(float(np.max(np.abs(s.z - z)))
                   for s, (_, z) in zip(self.steps, self.desktop, strict=True))

    @property
    def instructions(self) -> list[int]:
        return [s.instructions for s in self.steps if s.instructions is not None]

    @property
    def fits_f401re(self) -> bool:
        return self.footprint.flash <= F401RE_FLASH and self.footprint.ram <= F401RE_RAM


def pil_check(library: ScheduledLibrary, x: FloatArray, ref: FloatArray, precision: Precision,
              folder: Path, count_instructions: bool = True,
              timings: Mapping[str, cycles.Timing] | None = None) -> PilCheck:
    """Cross-build ``library``'s C with the recorded states ``x (n, nx)``, ``ref (n, nref)``,
    run it under QEMU and set its results beside the desktop library's."""
    desktop = [library.step(xi, ri)[1:3][::-1] for xi, ri in zip(x, ref, strict=True)]
    _, footprint = cross_build(harness_source(library.source, x[:1], ref[:1]), precision,
                               folder / f"{precision}_footprint")
    elf, _ = cross_build(harness_source(library.source, x, ref), precision,
                         folder / f"{precision}_run")
    return PilCheck(precision, footprint, run(elf, count_instructions, timings=timings), desktop)


def recorded_states(steps: pd.DataFrame, state_labels: Sequence[str],
                    target: Callable[[float], FloatArray], n: int) -> tuple[FloatArray, FloatArray]:
    """``n`` evenly spread controller calls of a run record's ``steps``: the states
    ``(n, nx)`` and the flattened previewed references ``target(t)`` ``(n, nref)``."""
    calls = record.controller_steps(steps)
    rows = calls.iloc[np.linspace(0, len(calls) - 1, n).round().astype(int)]
    x = rows[list(state_labels)].to_numpy(dtype=float)
    ref = np.stack([np.asarray(target(float(t))).ravel() for t in rows["t"]])
    return x, ref
