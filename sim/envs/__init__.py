"""Gymnasium environments of the RobChair digital twin; importing this module registers them.

Registered ids (lazy ``entry_point`` strings: nothing heavy is imported until :func:`gymnasium.make`):

* ``RobChair/Navigation-v0`` - reach a goal in the office scene with a decimated Kinect v2 (128x106)
  feeding the variable-height-voxel map; 300 agent steps (30 s at 10 Hz) per episode.
* ``RobChair/NavigationSonar-v0`` - the same task seen only through the two three-sonar arrays.

Example:
    >>> import gymnasium
    >>> import sim.envs  # registers the ids
    >>> env = gymnasium.make("RobChair/Navigation-v0")  # doctest: +SKIP

(``gymnasium.make("sim.envs:RobChair/Navigation-v0")`` imports this module by itself.)
"""

from __future__ import annotations

import gymnasium

ENV_IDS = ("RobChair/Navigation-v0", "RobChair/NavigationSonar-v0")

_REGISTRATIONS: dict[str, dict[str, object]] = {
    "RobChair/Navigation-v0": {"kwargs": {"scene": "office", "sensor": "kinect2", "sonars": False}},
    "RobChair/NavigationSonar-v0": {"kwargs": {"scene": "office", "sensor": None, "sonars": True}},
}

for _id, _extra in _REGISTRATIONS.items():
    # guarded so a module reload does not make gymnasium warn about overriding an id
    if _id not in gymnasium.registry:
        gymnasium.register(
            id=_id,
            entry_point="sim.envs.navigation:RobChairNavigationEnv",
            max_episode_steps=300,
            kwargs=dict(_extra["kwargs"]),  # type: ignore[call-overload]
        )

__all__ = ["ENV_IDS"]
