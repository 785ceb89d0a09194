"""The PyBullet digital twin of RobChair: world, scenes, robot model, simulated sensors, Gymnasium envs."""

from sim.errors import SimError

__all__ = ["SimError"]
