"""``python -m mpclab.tables PATH [PATH ...]``: the tables and the figure of any run records
(:mod:`mpclab.sweeps.report`; the entry point sits above the figure it draws)."""

from mpclab.sweeps.report import main

raise SystemExit(main())
