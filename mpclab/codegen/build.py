"""Compile C into a shared object once, cached on disk by a hash of what shaped it.

The library is named by a hash of the C source text, the compiler, its flags and any extra
key (the CasADi version for CasADi's generated code) in the cache folder (``$MPCLAB_CACHE``,
else ``~/.cache/mpclab``), so only the first build pays the compile. It is compiled under a
temporary name and renamed into place: parallel sweep workers that compile the same source at
once each write a whole file, and readers never see a partial one. :func:`compile_indexed`
also skips writing the source when a cheaper key of what shapes it was seen before.
"""

from __future__ import annotations

import hashlib
import logging
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from pathlib import Path

log = logging.getLogger("mpclab")

#: libraries compiled by this process (a cache hit does not count): for tests and reports
compile_count = 0


class CompileError(RuntimeError):
    """No C compiler, an unwritable cache, or a failed compile; the message says which."""


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


def source_key(source: str, compiler: str, flags: Sequence[str], extra: Sequence[str] = ()) -> str:
    """The cache key of a build: a hash of the source, the compiler's name, flags and extras,
    and of this CPU where a flag tunes the code for it (``-march=native``)."""
    text = "\n".join([source, Path(compiler).name, *flags, *extra, host_key(flags)])
    return hashlib.sha256(text.encode()).hexdigest()[:24]


def host_key(flags: Sequence[str]) -> str:
    """What names this CPU (model and instruction-set flags) if ``flags`` build for it, else
    ``""``: a library built with ``-march=native`` must not be loaded on another kind of CPU
    that shares the cache folder (a cluster's shared home)."""
    if not any("native" in flag for flag in flags):
        return ""
    try:
        info = Path("/proc/cpuinfo").read_text().splitlines()
    except OSError:
        return platform.processor() or platform.machine()
    keep = [line for line in info if line.split(":")[0].strip() in ("model name", "flags")]
    return "\n".join(sorted(set(keep))) or platform.machine()


#: seconds the compile of ``kb`` kB of C takes, ``S_PER_KB * kb + S_PER_KB2 * kb**2``, for
#: the notices' estimates: fitted to the Zumo NLPs at -O1 on a 2-core AMD EPYC (0.85 to 17 MB
#: of C, 7 to 290 s; -O0 is faster, -O2 and -O3 slower)
COMPILE_S_PER_KB = 5.3e-3
COMPILE_S_PER_KB2 = 6.7e-7


def compile_seconds(kb: float) -> float:
    """The rough wall time of compiling ``kb`` kB of C at ``-O1`` [s]."""
    return COMPILE_S_PER_KB * kb + COMPILE_S_PER_KB2 * kb * kb


def rough(seconds: float) -> str:
    """A rough duration in words: ``12 s``, ``5 min``, ``31 h``."""
    if seconds < 90:
        return f"{max(1, round(seconds))} s"
    return f"{round(seconds / 60)} min" if seconds < 5400 else f"{round(seconds / 3600)} h"


def announce(message: str) -> None:
    """Say what long work starts: on standard error at once (the console's log handler may be
    silenced while a solver is built, see :mod:`mpclab.core.native_output`) and in the run's log."""
    sys.stderr.write(f"mpclab: {message}\n")
    sys.stderr.flush()
    log.info("%s", message)


def compile_shared(
    source: str, prefix: str, flags: Sequence[str], extra_key: Sequence[str] = (),
    libs: Sequence[str] = (), header: str | None = None, keep_source: bool = False,
) -> Path:
    """The shared object of the C ``source``, compiled once and cached as ``PREFIX_KEY.so``;
    ``libs`` (``-L``, ``-l``, rpath options) follow the source on the command line and count
    in the key like the flags. With ``keep_source``, the source stays beside the library as
    ``PREFIX_KEY.c`` (and ``header``, if given, as ``PREFIX_KEY.h``): :func:`kept_source`.

    Raises
    ------
    CompileError
        When no C compiler is found, the cache folder cannot be written, or the compile fails
        (the compiler's message is kept).
    """
    global compile_count
    cc = find_compiler()
    if cc is None:
        raise CompileError("no C compiler found (set CC)")
    key = source_key(source, cc, [*flags, *libs], extra_key)
    folder = cache_dir()
    lib = folder / f"{prefix}_{key}.so"
    if lib.exists():
        if keep_source:
            _keep(lib, source, header)
        return lib
    try:
        folder.mkdir(parents=True, exist_ok=True)
        fd, src_name = tempfile.mkstemp(prefix=f".{prefix}_{key}.", suffix=".c", dir=folder)
    except OSError as exc:
        raise CompileError(f"cannot write the compile cache {folder} ({exc}; set "
                           "MPCLAB_CACHE)") from None
    with os.fdopen(fd, "w") as f:
        f.write(source)
    tmp_lib = src_name[:-2] + ".so"
    kb = len(source) // 1000
    announce(f"compiling {prefix} ({kb} kB of C, {' '.join(flags) or 'no flags'}; roughly "
             f"{rough(compile_seconds(kb))}): once, then cached in {folder}")
    t0 = time.perf_counter()
    try:
        subprocess.run([cc, "-fPIC", "-shared", *flags, src_name, "-o", tmp_lib, *libs, "-lm"],
                       check=True, capture_output=True, text=True)
        os.replace(tmp_lib, lib)  # atomic: a reader sees no file or a whole one
        compile_count += 1
        announce(f"compiled {prefix} in {time.perf_counter() - t0:.1f} s")
    except subprocess.CalledProcessError as exc:
        raise CompileError(f"compiling failed ({exc.stderr.strip()[:300]})") from None
    finally:
        for leftover in (src_name, tmp_lib):
            Path(leftover).unlink(missing_ok=True)
    if keep_source:
        _keep(lib, source, header)
    return lib


def kept_source(lib: Path) -> list[Path]:
    """The generated C kept beside the library ``lib`` (``.c``, then ``.h`` if there is one)."""
    return [p for p in (lib.with_suffix(".c"), lib.with_suffix(".h")) if p.is_file()]


def _keep(lib: Path, source: str, header: str | None) -> None:
    """Write ``source`` (and ``header``) beside ``lib`` unless already there, each whole
    (written under a temporary name and renamed, as the library)."""
    for suffix, text in ((".c", source), (".h", header)):
        path = lib.with_suffix(suffix)
        if text is None or path.is_file():
            continue
        try:
            fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", dir=lib.parent)
            with os.fdopen(fd, "w") as f:
                f.write(text)
            os.chmod(tmp, 0o644)  # readable like any source (mkstemp makes it private)
            os.replace(tmp, path)
        except OSError as exc:
            raise CompileError(f"cannot keep the generated C in {lib.parent} ({exc}; set "
                               "MPCLAB_CACHE)") from None


def compile_indexed(
    shape_key: str, source: Callable[[], str], prefix: str, flags: Sequence[str],
    extra_key: Sequence[str] = (),
) -> Path:
    """:func:`compile_shared` of ``source()``, without writing the source when a library was
    compiled before from what ``shape_key`` names.

    Writing the source can cost more than loading its library (CasADi generates the
    derivatives of an NLP to write its C: a quarter of a second for the Zumo NLP). So the
    cache also keeps an index, ``PREFIX_INDEX.lib``, from a cheap key of everything that
    shapes the source (``shape_key``: for CasADi the serialized problem and the solver's
    options; the compiler, flags and extras are added here) to the library compiled from it;
    an index entry whose library is gone is rebuilt.
    """
    cc = find_compiler()
    if cc is None:
        raise CompileError("no C compiler found (set CC)")
    folder = cache_dir()
    index = folder / f"{prefix}_{source_key(shape_key, cc, flags, extra_key)}.lib"
    try:
        lib = folder / index.read_text().strip()
        if lib.is_file():
            return lib
    except OSError:
        pass
    announce(f"writing the C of {prefix} (its derivatives generated; the compile follows)")
    lib = compile_shared(source(), prefix, flags, extra_key)
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{index.name}.", dir=folder)
        with os.fdopen(fd, "w") as f:
            f.write(lib.name)
        os.replace(tmp, index)  # atomic, like the library
    except OSError:
        pass  # no index: the next build writes the source again and finds the library
    return lib
