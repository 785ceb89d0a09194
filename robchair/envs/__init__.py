"""Gymnasium environments that drive the chair through the runtime (application floor).

The ids are registered by :mod:`sim.envs` with lazy entry points into :mod:`robchair.envs.navigation`.
"""
