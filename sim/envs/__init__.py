"""Gymnasium environments of the RobChair digital twin; importing this module registers them.

Registered ids (lazy ``entry_point`` strings: nothing heavy is imported until :func:`gymnasium.make`);
every id runs :class:`robchair.envs.navigation.RobChairNavigationEnv` at 10 Hz with 300 agent steps (30 s)
per episode. The ``-v1`` ids draw a new chair per episode (domain randomisation, see the class
docstring); the ``-v0`` ids keep the nominal chair.

* ``RobChair/Navigation-v0`` - the office scene, a decimated Kinect v2 (128x106) feeding the
  variable-height-voxel map.
* ``RobChair/NavigationSonar-v0`` - the same task seen only through the two three-sonar arrays.
* ``RobChair/Navigation-v1`` - the light observation: the Hokuyo URG-04LX laser scan (682 ranges),
  the six sonars, the egocentric local map that the chair's own map builds from both, the goal and
  the measured velocity; office scene.
* ``RobChair/NavigationRooms-v1`` - the light observation on a new random floor
  (:mod:`sim.rooms`, training seeds) every episode; ``room_seeds="eval"`` for evaluation floors.
* ``RobChair/NavigationKinect-v1`` - the light observation plus the decimated Kinect v2 in the map.
* ``RobChair/NavigationDynamic-v1`` - random floors with two people walking.
* ``RobChair/NavigationDiscrete-v1`` - the light observation with five discrete actions
  (:data:`robchair.envs.navigation.DISCRETE_ACTIONS`: stop, forward slow, forward fast, turn left, right).
* ``RobChair/SharedControl-v0`` - :class:`robchair.envs.shared_control.RobChairSharedControlEnv`: the
  light observation plus a simulated user's joystick; the action is the applied command, the reward
  trades progress and safety against agreement with the person; office scene.

Example:
    >>> import gymnasium
    >>> import sim.envs  # registers the ids
    >>> env = gymnasium.make("RobChair/Navigation-v1")  # doctest: +SKIP

(``gymnasium.make("sim.envs:RobChair/Navigation-v1")`` imports this module by itself.)
"""

from __future__ import annotations

import gymnasium

_LIGHT = {"sensor": None, "sonars": True, "laser": True}

_REGISTRATIONS: dict[str, dict[str, object]] = {
    "RobChair/Navigation-v0": {
        "scene": "office",
        "sensor": "kinect2",
        "sonars": False,
        "randomization": False,
    },
    "RobChair/NavigationSonar-v0": {
        "scene": "office",
        "sensor": None,
        "sonars": True,
        "randomization": False,
    },
    "RobChair/Navigation-v1": {"scene": "office", **_LIGHT},
    "RobChair/NavigationRooms-v1": {"scene": "rooms", **_LIGHT},
    "RobChair/NavigationKinect-v1": {"scene": "office", "sensor": "kinect2", "sonars": True},
    "RobChair/NavigationDynamic-v1": {"scene": "rooms", "walkers": 2, **_LIGHT},
    "RobChair/NavigationDiscrete-v1": {"scene": "office", "action_type": "discrete", **_LIGHT},
}
# v2: the v1 configurations with the probabilistic map (free space, people cleared, a three-valued
# occupancy patch: 0 free, 1 occupied, 2 unknown)
_REGISTRATIONS.update(
    {
        _id.replace("-v1", "-v2"): {**_kw, "map_kind": "probabilistic"}
        for _id, _kw in list(_REGISTRATIONS.items())
        if _id.endswith("-v1")
    }
)

_REGISTRATIONS["RobChair/SharedControl-v0"] = {"scene": "office", **_LIGHT}
_ENTRY_POINTS = {"RobChair/SharedControl-v0": "robchair.envs.shared_control:RobChairSharedControlEnv"}

ENV_IDS = tuple(_REGISTRATIONS)

for _id, _kwargs in _REGISTRATIONS.items():
    # guarded so a module reload does not make gymnasium warn about overriding an id
    if _id not in gymnasium.registry:
        gymnasium.register(
            id=_id,
            entry_point=_ENTRY_POINTS.get(_id, "robchair.envs.navigation:RobChairNavigationEnv"),
            max_episode_steps=300,
            kwargs=dict(_kwargs),
        )

__all__ = ["ENV_IDS"]
