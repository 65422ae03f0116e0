"""mpclab: declarative experiments in model predictive control of ground vehicles.

From Python (a notebook, a loop of your own)::

    import mpclab
    cfg = mpclab.compose(["+experiment=zumo_bug2", "seed=3"])   # or config_dir="my_confs"
    result = mpclab.run(cfg)          # result.steps, result.horizons, result.summary

The names below load on first use, so that ``python -m mpclab.cli.tables`` and the like do not
import the solvers.
"""

from __future__ import annotations

import importlib
from typing import Any

#: the Python API: name -> the module that defines it
API = {"compose": "mpclab.runner.single_run", "run": "mpclab.runner.single_run",
       "build_run": "mpclab.runner.single_run", "ComponentCache": "mpclab.runner.component_cache"}
__all__ = list(API)


def __getattr__(name: str) -> Any:
    if name not in API:
        raise AttributeError(f"module 'mpclab' has no attribute {name!r}")
    return getattr(importlib.import_module(API[name]), name)
