"""A generated scheduled controller as a standalone C folder for a board.

:func:`write_board` writes, for the tables of a switched scheduled controller
(:mod:`mpclab.codegen.scheduled`):

* ``mpc_controller.h``, ``mpc_controller.c``: ``mpc_step`` and its tables (``static const``:
  in flash), no dynamic memory, no operating system; ``mpc_real`` is ``double``, or
  ``float`` with ``-DMPC_SINGLE``;
* ``main.c``: an example control loop whose board functions (read the state, fill the
  reference, apply the inputs) replay recorded states and print each step's inputs through
  semihosting;
* ``startup.c``, ``f401re.ld``: the bare-metal start and the STM32F401RE's memory map of the
  processor-in-the-loop harness (:mod:`mpclab.codegen.pil`);
* ``Makefile``: ``arm-none-eabi-gcc`` with the PIL build's flags; ``make run`` runs the example
  on QEMU's ``netduinoplus2``;
* ``README.md``: the interface (state, input and reference layout) and how to build.

``python -m mpclab.cli.board`` builds a controller from a config and calls it.
"""

from __future__ import annotations

import shutil
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import numpy.typing as npt

from mpclab.codegen.cwriter import c_array
from mpclab.codegen.pil import BUILD_FLAGS, CM4_FLAGS, HARNESS, QEMU_BOARD
from mpclab.codegen.scheduled import ScheduledTables, scheduled_c, scheduled_h

FloatArray = npt.NDArray[np.float64]

NAME = "mpc_controller"
ELF = "controller.elf"
#: the files of a board folder, in the order :func:`write_board` writes them
FILES = (f"{NAME}.h", f"{NAME}.c", "main.c", "startup.c", "f401re.ld", "Makefile", "README.md")

_MAIN = """\
/* Example: the generated controller in a board's control loop.
 *
 * Every control period ({dt:g} s) a board reads the state, fills the reference preview,
 * calls mpc_step and applies the first MPC_NU moves. read_state, read_reference and
 * apply_inputs are what a port replaces: as written they replay {n} recorded state(s) and
 * print each step through semihosting (the debugger's console), so `make run` shows them. */
#include "{name}.h"

void pil_puts(const char *s); /* startup.c: semihosting's console */

#define EXAMPLE_STEPS {n}
{example_x}
{example_ref}

static void read_state(int k, mpc_real x[MPC_NX])
{{
    int i;
    for (i = 0; i < MPC_NX; ++i) x[i] = (mpc_real)example_x[k][i];
}}

static void read_reference(int k, mpc_real ref[MPC_NREF])
{{
    int i;
    for (i = 0; i < MPC_NREF; ++i) ref[i] = (mpc_real)example_ref[k][i];
}}

/* Numbers as text (no printf: nothing of the C library's I/O is linked). */
static char *put_int(char *p, unsigned long long v)
{{
    char digits[24];
    int n = 0;
    do {{ digits[n++] = (char)('0' + v % 10); v /= 10; }} while (v);
    while (n) *p++ = digits[--n];
    return p;
}}

static char *put_text(char *p, const char *s)
{{
    while (*s) *p++ = *s++;
    return p;
}}

static char *put_number(char *p, double v) /* with 9 decimals */
{{
    unsigned long long whole, frac, scale = 100000000ULL;
    if (v < 0) {{ *p++ = '-'; v = -v; }}
    whole = (unsigned long long)v;
    frac = (unsigned long long)((v - (double)whole) * 1e9 + 0.5);
    if (frac >= 1000000000ULL) {{ whole += 1; frac -= 1000000000ULL; }}
    p = put_int(p, whole);
    *p++ = '.';
    for (; scale; scale /= 10) *p++ = (char)('0' + (frac / scale) % 10);
    return p;
}}

static void apply_inputs(int code, int op, int iterations, const mpc_real u[MPC_NU])
{{
    char line[64 + MPC_NU * 32], *p = line;
    int i;
    p = put_int(put_text(p, "step: code "), (unsigned)code);
    p = put_int(put_text(p, ", operating point "), (unsigned)op);
    p = put_int(put_text(p, ", iterations "), (unsigned)iterations);
    p = put_text(p, ", u");
    for (i = 0; i < MPC_NU; ++i) p = put_number(put_text(p, " "), (double)u[i]);
    *p++ = '\\n';
    *p = 0;
    pil_puts(line);
}}

int main(void)
{{
    static mpc_real x[MPC_NX], ref[MPC_NREF], z[MPC_NZ];
    int k, op, iterations, code;
    for (k = 0; k < EXAMPLE_STEPS; ++k) {{ /* on a board: forever, once per period */
        read_state(k, x);
        read_reference(k, ref);
        code = mpc_step(x, ref, z, &op, &iterations);
        apply_inputs(code, op, iterations, z); /* z[0 .. MPC_NU - 1]: this period's inputs */
    }}
    pil_puts("done\\n");
    return 0;
}}
"""

_MAKEFILE = """\
# The generated controller and its example for an STM32F401RE (Cortex-M4F, 84 MHz):
#   make                     double precision (the FPU is single precision: doubles run in
#                            software routines)
#   make PRECISION=single    float, on the FPU (make clean first when switching)
#   make run                 the example on QEMU's {board} (an STM32F405, Cortex-M4F),
#                            printing through semihosting
CC = arm-none-eabi-gcc
SIZE = arm-none-eabi-size
QEMU = qemu-system-arm
CFLAGS = {cpu} {build}
ifeq ($(PRECISION),single)
CFLAGS += -DMPC_SINGLE
endif
LDFLAGS = -nostartfiles --specs=nano.specs -T f401re.ld -Wl,--gc-sections
SOURCES = {name}.c main.c startup.c

{elf}: $(SOURCES) {name}.h f401re.ld
\t$(CC) $(CFLAGS) $(SOURCES) $(LDFLAGS) -lm -o $@
\t$(SIZE) $@

run: {elf}
\t$(QEMU) -M {board} -display none -monitor none -serial null \\
\t  -semihosting-config enable=on,target=native -kernel {elf}

clean:
\trm -f {elf}

.PHONY: run clean
"""

_README = """\
# {title}

Generated by `python -m mpclab.cli.board {command}`; do not edit the controller's files,
export again.

A gain-scheduled linear MPC: {nop} operating points, prediction horizon {T} steps of
{dt:g} s, {nz} free variables, its QP solved by {qp}. No dynamic memory, no operating system:
`mpc_step` and its tables (in flash) are all it needs. `mpc_real` is `double`, or `float`
when compiled with `-DMPC_SINGLE`.

```c
int mpc_step(const mpc_real x[MPC_NX], const mpc_real ref[MPC_NREF], mpc_real z[MPC_NZ],
             int *op, int *iterations);   /* 0: the QP solved to optimality */
```

Call it once per control period ({dt:g} s):

- `x`, the state ({nx} values): {states}
- `ref`, the reference over the horizon: the reference state at t, t + dt, ...,
  t + {T} dt, {nx} values each in the order of `x` ({nref} values)
- `z`: the moves; apply `z[0]` .. `z[{nu_last}]` now: {inputs}

Files:

- `{name}.h`, `{name}.c`: the controller, `mpc_step` and its tables;
- `main.c`: an example control loop; replace `read_state`, `read_reference` and
  `apply_inputs` with the board's own (as written they replay {n} recorded state(s) and
  print each step; `expected_output.txt` is what the desktop build of the same C printed);
- `startup.c`, `f401re.ld`: a bare-metal start (vector table, memory set-up, FPU on,
  semihosting) and the STM32F401RE's memory map;
- `Makefile`: `arm-none-eabi-gcc` for the Cortex-M4F.

Build and run (Debian: `gcc-arm-none-eabi libnewlib-arm-none-eabi qemu-system-arm`):

    make                    # controller.elf, double precision; make PRECISION=single: float
    make run                # the example on QEMU's {board}
"""


def write_board(
    tables: ScheduledTables, out_dir: Path, *, states: Sequence[str], inputs: Sequence[str],
    dt: float, x: FloatArray, ref: FloatArray, title: str = "Generated MPC controller",
    command: str = "",
) -> list[Path]:
    """Write the board folder of ``tables`` into ``out_dir`` (made if missing); the example
    replays the states ``x (n, nx)`` with their previewed references ``ref (n, nref)``.
    Returns the files written (:data:`FILES`)."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    x, ref = np.atleast_2d(np.asarray(x, dtype=float)), np.atleast_2d(np.asarray(ref, dtype=float))
    t = tables
    nref = (t.horizon + 1) * t.nx
    if x.shape[1] != t.nx or ref.shape != (len(x), nref):
        raise ValueError(f"example states must be (n, {t.nx}) and references (n, {nref}), "
                         f"got {x.shape} and {ref.shape}")
    texts = {
        f"{NAME}.h": scheduled_h(t, NAME),
        f"{NAME}.c": scheduled_c(t, NAME, header_file=f"{NAME}.h"),
        "main.c": _MAIN.format(dt=dt, n=len(x), name=NAME, example_x=c_array("example_x", x),
                               example_ref=c_array("example_ref", ref)),
        "Makefile": _MAKEFILE.format(board=QEMU_BOARD, cpu=" ".join(CM4_FLAGS),
                                     build=" ".join(BUILD_FLAGS), name=NAME, elf=ELF),
        "README.md": _README.format(
            title=title, command=command, nop=t.n_ops, T=t.horizon, dt=dt, nz=t.nz,
            qp=t.qp.value.replace("_", " "), nx=t.nx, states=", ".join(states), nref=nref,
            nu_last=t.nu - 1, inputs=", ".join(inputs), name=NAME, n=len(x), board=QEMU_BOARD),
    }
    written = []
    for name in FILES:
        path = out / name
        if name in texts:
            path.write_text(texts[name])
        else:
            shutil.copyfile(HARNESS / name, path)
        written.append(path)
    return written
