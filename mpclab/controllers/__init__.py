"""Solver backends: one file per backend, all behind :class:`~mpclab.controllers.base.Controller`."""
