"""Compiled NLP functions for the CasADi backend, cached on disk by their C source.

An ``nlpsol`` built from the symbolic problem writes its functions (cost, constraints and
their derivatives) as C (``generate_dependencies``); the C compiler turns them into a shared
library, from which an ``nlpsol`` of the same plugin is built again. The library is named by
a hash of everything that shaped it (the C source text, the compiler, its flags and the
CasADi version) in the cache folder (``$MPCLAB_CACHE``, else ``~/.cache/mpclab``), so only
the first run pays the compile (tens of seconds for the Zumo NLP). It is compiled under a
temporary name and renamed into place: parallel sweep workers that compile the same source
at once each write a whole file, and readers never see a partial one.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
import tempfile
import warnings
from pathlib import Path

import casadi as ca

#: optimization level of the compiled NLP functions (see experiments/zumo/SOLVERS.md)
DEFAULT_FLAGS = ("-O1",)
#: libraries compiled by this process (a cache hit does not count): for tests and reports
compile_count = 0


def cache_dir() -> Path:
    """Where compiled libraries are kept: ``$MPCLAB_CACHE`` or ``~/.cache/mpclab``."""
    root = os.environ.get("MPCLAB_CACHE") or Path.home() / ".cache" / "mpclab"
    return Path(root)


def find_compiler() -> str | None:
    """The C compiler: ``$CC`` if set, else the first of gcc, cc, clang on the path."""
    names = [os.environ["CC"]] if os.environ.get("CC") else ["gcc", "cc", "clang"]
    for name in names:
        path = shutil.which(name)
        if path:
            return path
    return None


def compiled_nlp(solver: ca.Function, flags: tuple[str, ...] = DEFAULT_FLAGS) -> Path | None:
    """The shared library of ``solver``'s NLP functions, compiled once and cached.

    None (with a warning) when no C compiler is found or the compile fails: the caller then
    keeps the uncompiled functions.
    """
    global compile_count
    cc = find_compiler()
    if cc is None:
        warnings.warn("controller.jit: no C compiler found (set CC); the NLP functions run "
                      "uncompiled", RuntimeWarning, stacklevel=2)
        return None
    with tempfile.TemporaryDirectory(prefix="mpclab_nlp_") as tmp:
        cwd = os.getcwd()
        os.chdir(tmp)  # generate_dependencies writes into the working folder
        try:
            solver.generate_dependencies("nlp.c")
        finally:
            os.chdir(cwd)
        source = (Path(tmp) / "nlp.c").read_text()
    key = hashlib.sha256(
        "\n".join([source, Path(cc).name, *flags, ca.__version__]).encode()
    ).hexdigest()[:24]
    folder = cache_dir()
    lib = folder / f"nlp_{key}.so"
    if lib.exists():
        return lib
    try:
        folder.mkdir(parents=True, exist_ok=True)
        fd, src_name = tempfile.mkstemp(prefix=f".nlp_{key}.", suffix=".c", dir=folder)
    except OSError as exc:
        warnings.warn(f"controller.jit: cannot write the compile cache {folder} ({exc}; set "
                      "MPCLAB_CACHE); the NLP functions run uncompiled", RuntimeWarning,
                      stacklevel=2)
        return None
    with os.fdopen(fd, "w") as f:
        f.write(source)
    tmp_lib = src_name[:-2] + ".so"
    try:
        subprocess.run([cc, "-fPIC", "-shared", *flags, src_name, "-o", tmp_lib, "-lm"],
                       check=True, capture_output=True, text=True)
        os.replace(tmp_lib, lib)  # atomic: a reader sees no file or a whole one
        compile_count += 1
    except subprocess.CalledProcessError as exc:
        warnings.warn(f"controller.jit: compiling the NLP failed ({exc.stderr.strip()[:300]}); "
                      "the NLP functions run uncompiled", RuntimeWarning, stacklevel=2)
        return None
    finally:
        for leftover in (src_name, tmp_lib):
            Path(leftover).unlink(missing_ok=True)
    return lib
