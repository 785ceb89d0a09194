"""Error root of the robchair package."""


class RobChairError(Exception):
    """Root of every error the robchair package raises on purpose."""


class ConfigError(RobChairError, ValueError):
    """A configuration file or value is invalid (the message names the field, value and expectation)."""
