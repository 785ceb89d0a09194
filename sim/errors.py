"""Error root of the simulation package."""


class SimError(Exception):
    """Root of every error the simulator raises on purpose."""


class ScenarioError(SimError, ValueError):
    """A scenario or scene file is invalid (the message names the file, key and reason)."""


class SimulationDivergedError(SimError, RuntimeError):
    """The physics produced a non-finite state."""
