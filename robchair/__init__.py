"""RobChair digital twin: the chair's model (:mod:`robchair.platform`), the drive loop, perception and CLI."""

__version__ = "0.1.0"
