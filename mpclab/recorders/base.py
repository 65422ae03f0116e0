"""The recorder interface: the runner logs every step to it and closes it in a ``finally``."""

from __future__ import annotations

from typing import Any

from mpclab.config.registry import component


class Recorder:
    """Base class; the default does nothing (``recorder=none``)."""

    def start(self, run: Any) -> None:
        """Called once before the first step with the run's plant, scenario and controller."""

    def log_step(self, k: int, t: float, x: Any, step: Any, ctx: Any) -> None:
        """Called after each controller call with the state, the ControlStep and context."""

    def finish(self, x: Any, t: float, summary: dict[str, Any]) -> None:
        """Called once after the last step with the final state and the summary."""

    def close(self) -> None:
        """Release files; always called."""


component("recorder", "none")(Recorder)
