"""The navigation environments' error class."""

from __future__ import annotations

from sim.errors import SimError


class NavigationEnvError(SimError, ValueError):
    """An argument of the navigation environment (or of its reset options / actions) is invalid."""
