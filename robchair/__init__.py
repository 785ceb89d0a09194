"""RobChair digital twin: platform spec, kinematics, motor control design, runtime and CLI."""

from robchair.errors import RobChairError

__all__ = ["RobChairError"]
__version__ = "0.1.0"
