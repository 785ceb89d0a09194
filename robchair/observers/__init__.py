"""Observers of the drive loop: hooks the runtime calls (dm_control-style lifecycle).

An observer subclasses :class:`robchair.loop_types.Observer` and overrides any of its hooks:
``episode_start`` (after the backend's first reading), ``before_cycle``, ``after_cycle`` (with the
cycle's :class:`robchair.loop_types.CycleResult`) and ``episode_end`` (with the
:class:`robchair.loop_types.RunResult`, also after a run that ended by an error); it reads the loop
through :class:`robchair.loop_types.LoopView`. Observers here: the run recorder
(:mod:`robchair.observers.recorder`), the time series (:mod:`robchair.observers.timeseries`), the motor
controller's diagnostics (:mod:`robchair.observers.diagnostics`) and the simulation's ground-truth
evaluation (:mod:`robchair.observers.evaluation`).
"""
