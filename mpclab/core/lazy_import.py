"""Heavy optional dependencies imported when first used, not when mpclab starts.

Composing a config imports every component module (each registers its schema), so a module's
top-level imports are paid by every run. CVXPY costs about 0.6 s to import; with
``cp = lazy_import("cvxpy")`` a CasADi-only run never pays it, and a CVXPY run pays it at its
first use of ``cp``. Figures draw with :func:`pyplot` (matplotlib's pyplot costs about 0.5 s):
a run or a sweep without figures never imports it.
"""

from __future__ import annotations

import importlib.util
import sys
from types import ModuleType


def lazy_import(name: str) -> ModuleType:
    """The module ``name``, loaded on first attribute access (already loaded: returned)."""
    if name in sys.modules:
        return sys.modules[name]
    spec = importlib.util.find_spec(name)
    if spec is None or spec.loader is None:
        raise ModuleNotFoundError(f"No module named {name!r}", name=name)
    loader = importlib.util.LazyLoader(spec.loader)
    spec.loader = loader
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    loader.exec_module(module)
    return module


def pyplot() -> ModuleType:
    """``matplotlib.pyplot`` on the Agg backend (figures are written to files, no display),
    imported at the first figure."""
    if "matplotlib.pyplot" not in sys.modules:
        import matplotlib

        matplotlib.use("Agg")
    return importlib.import_module("matplotlib.pyplot")
