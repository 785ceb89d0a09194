"""Action and observation spaces of the navigation environment; a step's sensing as an observation.

Pure glue between the runtime's last cycle (sensor readings, the perception stage's map) and the
Gymnasium spaces; nothing here touches the simulation.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import numpy.typing as npt
from gymnasium import spaces

from robchair.platform.kinematics import DiffDrive, Pose2D
from sim.envs.errors import NavigationEnvError
from sim.envs.geometry import egocentric_patch, egocentric_values, goal_in_robot_frame

SPEED_OBS_FACTOR = 1.5  # the velocity box holds measured overshoot beyond the command limits
ELEVATION_MAX = 2.5  # m, top of the elevation observation's box
#: Discrete actions as normalised (v, w) (times ``max_speed`` m/s and ``max_yaw_rate`` rad/s):
#: 0 stop, 1 forward slow, 2 forward fast, 3 turn left on the spot, 4 turn right on the spot.
#: Cell values of the three-valued ``occupancy`` patch (``map_kind="probabilistic"``); outside the
#: map is unknown.
PATCH_FREE, PATCH_OCCUPIED, PATCH_UNKNOWN = 0, 1, 2
DISCRETE_ACTIONS = ((0.0, 0.0), (0.3, 0.0), (0.7, 0.0), (0.0, 0.5), (0.0, -0.5))


def action_space(action_type: str) -> spaces.Space[Any]:
    """``Box(-1, 1, (2,), float32)`` for ``"continuous"``, ``Discrete(5)`` for ``"discrete"``."""
    if action_type == "discrete":
        return spaces.Discrete(len(DISCRETE_ACTIONS))
    return spaces.Box(-1.0, 1.0, shape=(2,), dtype=np.float32)


def action_to_twist(
    action: Any, space: spaces.Space[Any], drive: DiffDrive, max_speed: float, max_yaw_rate: float
) -> tuple[float, float]:
    """The body twist (v m/s, w rad/s) an action asks for, within the drive's limits.

    A continuous action is clipped to the unit box, scaled by ``max_speed`` and ``max_yaw_rate``, then
    scaled down uniformly so no motor exceeds its maximum RPM (:meth:`DiffDrive.limit`).

    Raises:
        NavigationEnvError: not an action of ``space`` (discrete; a bool is not one), or not two finite
            real numbers of shape (2,) (a string, a bool or complex array, shape (1, 2) or (2, 1)).
    """
    if isinstance(space, spaces.Discrete):
        if isinstance(action, bool | np.bool_) or not space.contains(action):
            raise NavigationEnvError(
                f"action={action!r}: expected an integer in [0, {len(DISCRETE_ACTIONS)})"
            )
        action = DISCRETE_ACTIONS[int(action)]
    try:
        raw = np.asarray(action)
    except (TypeError, ValueError):  # e.g. a ragged sequence
        raise _bad_action(action, "") from None
    if raw.dtype.kind not in "iuf":  # bool, complex, str, object: not two real numbers
        raise _bad_action(action, f"dtype {raw.dtype} is not a real number type; ")
    if raw.shape != (2,):
        raise _bad_action(action, f"shape {raw.shape}; ")
    v, w = float(raw[0]), float(raw[1])
    if not (math.isfinite(v) and math.isfinite(w)):
        raise _bad_action(action, "")
    return drive.limit(min(max(v, -1.0), 1.0) * max_speed, min(max(w, -1.0), 1.0) * max_yaw_rate)


def clip_value(x: float, lo: float, hi: float) -> float:
    """``numpy.clip`` of one value (NaN stays, and so does the value on a tie with a bound)."""
    x = lo if x < lo else x
    return hi if x > hi else x


def _bad_action(action: Any, what: str) -> NavigationEnvError:
    """The error for an action that is not two finite real numbers (its repr on one line)."""
    shown = " ".join(repr(action).split())  # built only on error: an array's repr costs ~2 ms
    return NavigationEnvError(
        f"action={shown}: {what}expected two finite real numbers (v, w) in [-1, 1], shape (2,)"
    )


class ObservationBuilder:
    """The observation space, and the observation of a step from the runtime's last cycle.

    Args:
        grid: the episode map's grid.
        patch_shape, patch_cell, patch_behind: the egocentric patch (see :func:`egocentric_patch`).
        drive: the chair's kinematics (velocity limits, RPM -> twist).
        max_goal_obs: upper bound of the goal distance, m.
        sonar_max_range: the sonars' maximum range, m (None: no sonar observation).
        laser_model: the laser's :class:`sim.laser.LaserModel` (None: no laser observation).
        depth_model: the Kinect model of the ``depth`` observation (None: none).
        elevation: add the ``elevation`` observation.
        three_valued: the ``occupancy`` patch is three-valued (:data:`PATCH_FREE`, :data:`PATCH_OCCUPIED`,
            :data:`PATCH_UNKNOWN`) from a probabilistic map's codes; otherwise 1 = occupied, else 0.
    """

    def __init__(
        self,
        grid: Any,
        patch_shape: tuple[int, int],
        patch_cell: float,
        patch_behind: float,
        drive: DiffDrive,
        max_goal_obs: float,
        *,
        sonar_max_range: float | None = None,
        laser_model: Any = None,
        depth_model: Any = None,
        elevation: bool = False,
        three_valued: bool = False,
    ) -> None:
        self.grid = grid
        self.patch = (patch_shape, patch_cell, patch_behind)
        self.drive = drive
        self.max_goal_obs = float(max_goal_obs)
        self.sonar_max_range = sonar_max_range
        self.laser_model = laser_model
        self.elevation = bool(elevation)
        self.three_valued = bool(three_valued)
        self.vel_high = np.array(
            [SPEED_OBS_FACTOR * drive.max_speed, SPEED_OBS_FACTOR * drive.max_yaw_rate], np.float32
        )
        self._vh = (float(self.vel_high[0]), float(self.vel_high[1]))  # the float32 limits, exactly
        obs: dict[str, spaces.Space[Any]] = {
            "occupancy": spaces.Box(
                0, PATCH_UNKNOWN if three_valued else 1, shape=patch_shape, dtype=np.uint8
            ),
            "goal": spaces.Box(
                np.array([0.0, -math.pi], np.float32),
                np.array([self.max_goal_obs, math.pi], np.float32),
                dtype=np.float32,
            ),
            "velocity": spaces.Box(-self.vel_high, self.vel_high, dtype=np.float32),
        }
        self.sonar: npt.NDArray[np.float32] | None = None
        self.laser: npt.NDArray[np.float32] | None = None
        self.depth: npt.NDArray[np.float32] | None = None
        if sonar_max_range is not None:
            obs["sonar"] = spaces.Box(0.0, sonar_max_range, shape=(6,), dtype=np.float32)
            self.sonar = np.zeros(6, dtype=np.float32)
        if laser_model is not None:
            obs["laser"] = spaces.Box(
                0.0, laser_model.range_max, shape=(laser_model.n_beams,), dtype=np.float32
            )
            self.laser = np.zeros(laser_model.n_beams, dtype=np.float32)
        if depth_model is not None:
            shape = (int(depth_model.height), int(depth_model.width))
            self.depth_max = float(depth_model.max_range_m)
            obs["depth"] = spaces.Box(0.0, self.depth_max, shape=shape, dtype=np.float32)
            self.depth = np.zeros(shape, dtype=np.float32)
        if self.elevation:
            obs["elevation"] = spaces.Box(0.0, ELEVATION_MAX, shape=patch_shape, dtype=np.float32)
        self.space = spaces.Dict(obs)

    def take_readings(self, sonars: Any, scan: Any, depth_frame: Any) -> None:
        """Keep the cycle's sensor readings (a sensor that gave nothing keeps its last values).

        Args:
            sonars: ``[(array name, SonarArrayReading)]`` in the arrays' order (left, then right).
            scan: the laser's :class:`hw.interfaces.LaserScan` (REP-117 ranges) or None.
            depth_frame: the depth camera's :class:`hw.interfaces.DepthFrame` or None.
        """
        if self.sonar is not None and sonars:
            rmax = float(self.sonar_max_range)  # type: ignore[arg-type]
            # a range that is not finite (no echo) is the maximum; six values: plain floats
            rr = [float(r) for _, reading in sonars for r in reading.ranges_m]
            vals = [clip_value(r, 0.0, rmax) if math.isfinite(r) else rmax for r in rr]
            self.sonar = np.array(vals, dtype=np.float32)
        if self.laser is not None and scan is not None:
            # +inf: nothing within range_max; -inf: closer than range_min (an obstacle at the sensor);
            # then clipped to the box (noise may pass range_max)
            from robchair.envs._obs_kernels import laser_observation  # numba: imported when first used

            r = scan.ranges
            if isinstance(r, np.ndarray) and r.ndim == 1 and r.dtype in (np.float32, np.float64):
                self.laser = laser_observation(r, self.laser_model.range_max)
            else:
                self.laser = laser_observation(np.asarray(r, dtype=np.float64), self.laser_model.range_max)
        if self.depth is not None and depth_frame is not None:  # the camera's x (REP-103); 0 = nothing
            z = np.asarray(depth_frame.points[..., 0], dtype=np.float64)
            self.depth = np.clip(np.nan_to_num(z, nan=0.0), 0.0, self.depth_max).astype(np.float32)

    def observation(
        self,
        occupied: npt.NDArray[np.bool_],
        map_: Any,
        pose: Pose2D,
        goal: tuple[float, float],
        wheel_rpm: tuple[float, float],
        codes: npt.NDArray[np.int8] | None = None,
    ) -> dict[str, np.ndarray]:
        """The observation at ``pose`` (the pose the chair believes).

        Args:
            occupied: the episode map's 2D occupancy in the height band (bool, grid shape).
            map_: the episode's VHV map (for ``elevation``).
            pose: the chair's pose estimate.
            goal: the goal (x, y) in the map frame.
            wheel_rpm: the measured motor speeds (left, right), RPM.
            codes: with ``three_valued``, the map's ``nav_msgs/OccupancyGrid`` codes in the height band
                (int8, grid shape: 100 occupied, 0 free, -1 unknown).

        Raises:
            NavigationEnvError: ``three_valued`` without ``codes``.
        """
        shape, cell, behind = self.patch
        dist, bearing = goal_in_robot_frame(pose, goal)
        v, w = self.drive.twist_from_rpm(*wheel_rpm)  # what the encoders say
        if self.three_valued:
            if codes is None:
                raise NavigationEnvError("a three-valued occupancy observation needs the map's codes")
            values = np.where(codes == 100, PATCH_OCCUPIED, np.where(codes == 0, PATCH_FREE, PATCH_UNKNOWN))
            patch = egocentric_values(
                values.astype(np.uint8), self.grid, pose, shape, cell, behind, PATCH_UNKNOWN
            )
        else:
            patch = egocentric_patch(occupied, self.grid, pose, shape, cell, behind)
        vw = (float(np.float32(v)), float(np.float32(w)))  # the float32 box's clip, value by value
        obs: dict[str, np.ndarray] = {
            "occupancy": patch,
            "goal": np.array([min(dist, self.max_goal_obs), bearing], dtype=np.float32),
            "velocity": np.array([clip_value(v32, -h, h) for v32, h in zip(vw, self._vh)], np.float32),
        }
        if self.sonar is not None:
            obs["sonar"] = self.sonar.copy()
        if self.laser is not None:
            obs["laser"] = self.laser.copy()
        if self.depth is not None:
            obs["depth"] = self.depth.copy()
        if self.elevation:
            from mapping.derived import elevation

            top, _ = elevation(map_)
            top = np.clip(np.nan_to_num(top, nan=0.0), 0.0, ELEVATION_MAX).astype(np.float32)
            obs["elevation"] = egocentric_values(top, self.grid, pose, shape, cell, behind)
        return obs


def step_info(
    gt: Pose2D, pose: Pose2D, distance: float, collided: bool, reached: bool, goal: tuple[float, float],
    sim_time: float, terms: dict[str, float] | None, dynamics: Any,
) -> dict[str, Any]:  # fmt: skip
    """The ``info`` of a step before the runtime's parts (``safety``, ``command``...): the true
    ``distance`` to the goal, collision and success, the true and the believed pose, the goal, the
    simulated time (s), the reward terms (None at a reset) and the episode's dynamics."""
    info: dict[str, Any] = {
        "distance": distance,
        "collision": collided,
        "is_success": reached,
        "pose": (gt.x, gt.y, gt.theta),
        "pose_estimate": (pose.x, pose.y, pose.theta),
        "goal": goal,
        "sim_time": sim_time,
    }
    if terms is not None:
        info["reward_terms"] = terms
    info["dynamics"] = dynamics.as_dict()
    return info
