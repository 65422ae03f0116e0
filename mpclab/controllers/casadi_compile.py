"""Compiled NLP functions for the CasADi backend, cached on disk by their C source.

An ``nlpsol`` built from the symbolic problem writes its functions (cost, constraints and
their derivatives) as C (``generate_dependencies``); the C compiler turns them into a shared
library (:func:`mpclab.codegen.build.compile_shared`: cached by a hash of the C source, the
compiler, its flags and the CasADi version), from which an ``nlpsol`` of the same plugin is
built again. Only the first run pays the compile (tens of seconds for the Zumo NLP), and a
run that finds its library does not write the C again (:func:`problem_key`).
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

from mpclab.codegen.build import CompileError, compile_indexed

#: optimization level of the compiled NLP functions (see experiments/zumo/SOLVERS.md)
DEFAULT_FLAGS = ("-O1",)


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
        warnings.warn(f"controller.jit: {exc}; the NLP functions run uncompiled",
                      RuntimeWarning, stacklevel=2)
        return None
