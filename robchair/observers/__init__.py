"""Observers of the drive loop: hooks the runtime calls (dm_control-style lifecycle).

An observer overrides any of :meth:`Observer.episode_start` (after the backend's first reading),
:meth:`Observer.before_cycle`, :meth:`Observer.after_cycle` (with the cycle's
:class:`robchair.runtime.CycleResult`) and :meth:`Observer.episode_end` (with the
:class:`robchair.runtime.RunResult`, also after a run that ended by an error). Observers here: the
run recorder (:mod:`robchair.observers.recorder`), the simulation's ground-truth evaluation
(:mod:`robchair.observers.evaluation`) and the pictures (:mod:`robchair.observers.pictures`).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from robchair.runtime import CycleResult, RunResult, Runtime


class Observer:
    """Base class with empty hooks; an exception raised in a hook stops the chair and ends the run."""

    def episode_start(self, runtime: Runtime) -> None:
        """Called once, after the first motor reading and before the first cycle."""

    def before_cycle(self, runtime: Runtime, k: int) -> None:
        """Called at the start of cycle ``k`` (before any sensor is read)."""

    def after_cycle(self, runtime: Runtime, cycle: CycleResult) -> None:
        """Called after the cycle's command was written."""

    def episode_end(self, runtime: Runtime, result: RunResult) -> None:
        """Called once at the end of the run (the chair has been commanded to stop)."""
