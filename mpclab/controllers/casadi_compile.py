"""Compiled NLP functions for the CasADi backend, cached on disk by their C source.

An ``nlpsol`` built from the symbolic problem writes its functions (cost, constraints and
their derivatives) as C (``generate_dependencies``); the C compiler turns them into a shared
library (:func:`mpclab.codegen.build.compile_shared`: cached by a hash of the C source, the
compiler, its flags and the CasADi version), from which an ``nlpsol`` of the same plugin is
built again. Only the first run pays the compile (tens of seconds for the Zumo NLP).
"""

from __future__ import annotations

import os
import tempfile
import warnings
from collections.abc import Callable
from pathlib import Path

import casadi as ca

from mpclab.codegen.build import CompileError, compile_shared

#: optimization level of the compiled NLP functions (see experiments/zumo/SOLVERS.md)
DEFAULT_FLAGS = ("-O1",)


def generated_c(write: Callable[[str], object]) -> str:
    """The C that ``write(file name)`` (a CasADi ``generate`` method, which writes into the
    working folder) produces, read back from a temporary folder."""
    with tempfile.TemporaryDirectory(prefix="mpclab_nlp_") as tmp:
        cwd = os.getcwd()
        os.chdir(tmp)
        try:
            write("nlp.c")
        finally:
            os.chdir(cwd)
        return (Path(tmp) / "nlp.c").read_text()


def compiled_nlp(solver: ca.Function, flags: tuple[str, ...] = DEFAULT_FLAGS) -> Path | None:
    """The shared library of ``solver``'s NLP functions, compiled once and cached.

    None (with a warning) when no C compiler is found or the compile fails: the caller then
    keeps the uncompiled functions.
    """
    source = generated_c(solver.generate_dependencies)
    try:
        return compile_shared(source, "nlp", flags, extra_key=(ca.__version__,))
    except CompileError as exc:
        warnings.warn(f"controller.jit: {exc}; the NLP functions run uncompiled",
                      RuntimeWarning, stacklevel=2)
        return None
