"""Compiled NLP functions for the CasADi backend, cached on disk by their C source.

An ``nlpsol`` built from the symbolic problem writes its functions (cost, constraints and
their derivatives) as C (``generate_dependencies``); the C compiler turns them into a shared
library (:func:`mpclab.codegen.build.compile_shared`: cached by a hash of the C source, the
compiler, its flags and the CasADi version), from which an ``nlpsol`` of the same plugin is
built again. Only the first run pays the compile (tens of seconds for the Zumo NLP), and a
run that finds its library does not write the C again (:func:`problem_key`).

A long horizon makes all of it long (the compile grows faster than the C):
:func:`announce_long_build` says so before the build starts, with an estimate from the size
of the NLP.
"""

from __future__ import annotations

import json
import os
import tempfile
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any

import casadi as ca

from mpclab.codegen.build import (
    CompileError,
    announce,
    cache_dir,
    compile_indexed,
    compile_seconds,
    rough,
)

#: optimization level of the compiled NLP functions (see experiments/zumo/SOLVERS.md)
DEFAULT_FLAGS = ("-O1",)

#: per operation of an NLP's cost and constraints (``n_instructions``), measured on the Zumo
#: NLPs (horizons 10 to 5000, AMD EPYC, 2 cores): building the problem and its cache key [s],
#: writing its C with the derivatives [s], and the size of that C [kB]
BUILD_S_PER_OP = 1.7e-5
WRITE_S_PER_OP = 5e-5
C_KB_PER_OP = 0.25
#: a build estimated to take longer than this is announced before it starts [s]
LONG_BUILD_S = 60.0
#: the horizon from which a build is estimated first (the estimate builds two one- and
#: two-step NLPs, 10-25 ms; a shorter horizon's build is short)
ESTIMATE_FROM_HORIZON = 25


def operations(nlp: dict[str, Any]) -> int:
    """The size of an NLP: the operations of its cost and constraints."""
    return ca.Function("nlp", [nlp["x"], nlp["p"]], [nlp["f"], nlp["g"]]).n_instructions()


def announce_long_build(size_at: Callable[[int], int], horizon: int, compiled: bool) -> float:
    """Say before it starts that building an NLP of ``horizon`` steps (compiling its
    functions too if ``compiled``) will take minutes, if it will; return the estimate [s]
    (0 below :data:`ESTIMATE_FROM_HORIZON`, not estimated).

    ``size_at(T)``: the :func:`operations` of the NLP with a horizon of ``T`` steps, asked
    for ``T`` = 1 and 2 (milliseconds): its size grows linearly with the horizon.
    """
    if horizon < ESTIMATE_FROM_HORIZON:
        return 0.0
    one, two = size_at(1), size_at(2)
    ops = one + (horizon - 1) * (two - one)
    build, kb = ops * BUILD_S_PER_OP, ops * C_KB_PER_OP
    compile_s = ops * WRITE_S_PER_OP + compile_seconds(kb) if compiled else 0.0
    if build + compile_s > LONG_BUILD_S:
        text = f"controller.horizon={horizon}: an NLP of about {ops:,} operations; building " \
            f"it takes roughly {rough(build)}"
        if compiled:
            text += (f", then writing and compiling its C (about {kb / 1e3:,.0f} MB) roughly "
                     f"{rough(compile_s)} unless it was compiled before (cached in "
                     f"{cache_dir()}); a shorter controller.horizon builds much faster")
        announce(text)
    return build + compile_s


def generated_c(write: Callable[[str], object]) -> str:
    """The C that ``write(file name)`` (a CasADi ``generate`` method, which writes into the
    working folder) produces, read back from a temporary folder."""
    return generated_c_and_h(write)[0]


def generated_c_and_h(write: Callable[[str], object]) -> tuple[str, str | None]:
    """:func:`generated_c`, and the header ``write`` wrote beside it (None: none)."""
    with tempfile.TemporaryDirectory(prefix="mpclab_nlp_") as tmp:
        cwd = os.getcwd()
        os.chdir(tmp)
        try:
            write("nlp.c")
        finally:
            os.chdir(cwd)
        header = Path(tmp) / "nlp.h"
        return ((Path(tmp) / "nlp.c").read_text(),
                header.read_text() if header.is_file() else None)


def problem_key(nlp: dict[str, Any], plugin: str, opts: dict[str, Any]) -> str:
    """What shapes an ``nlpsol``'s generated C: its problem, serialized (about 10 ms for the
    Zumo NLP, where generating the C takes a quarter of a second), the plugin and options."""
    fn = ca.Function("nlp", [nlp["x"], nlp["p"]], [nlp["f"], nlp["g"]])
    return "\n".join([fn.serialize(), plugin, json.dumps(opts, sort_keys=True, default=str)])


def compiled_nlp(
    nlp: dict[str, Any], plugin: str, opts: dict[str, Any],
    flags: tuple[str, ...] = DEFAULT_FLAGS,
) -> Path | None:
    """The shared library of the NLP functions of ``nlpsol(plugin, nlp, opts)``, compiled once
    and cached (indexed by :func:`problem_key`: a cached library is found without writing C).

    None (with a warning) when no C compiler is found or the compile fails: the caller then
    keeps the uncompiled functions.
    """
    def source() -> str:
        return generated_c(ca.nlpsol("mpc", plugin, nlp, opts).generate_dependencies)

    try:
        return compile_indexed(problem_key(nlp, plugin, opts), source, "nlp", flags,
                               extra_key=(ca.__version__,))
    except CompileError as exc:
        warnings.warn(f"controller.build.jit: {exc}; the NLP functions run uncompiled",
                      RuntimeWarning, stacklevel=2)
        return None
