"""The drive loop's settings: :class:`RuntimeConfig` (rate, sensor periods, map kind) and run durations.

Loaded from a ``[runtime]`` TOML table or given in code; :class:`robchair.runtime.Runtime` runs with
them, and the commands check a ``--duration`` with :func:`check_duration_s` before they open a chair.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from robchair.perception import MAP_KINDS
from robchair.platform.config import ConfigSource, ConfigTable, bounds, check_dataclass, load_dataclass
from robchair.platform.errors import ConfigError

__all__ = ["MAX_DURATION_S", "RuntimeConfig", "check_duration_s"]

#: longest run, s: its stamps stay within int64 nanoseconds (9.2e9 s) with a margin
MAX_DURATION_S = 1e9


def check_duration_s(duration_s: float, what: str = "duration_s") -> float:
    """``duration_s`` as a float if it is a finite number of seconds in (0, :data:`MAX_DURATION_S`].

    Raises:
        ConfigError: ``<what> = <value>: expected ...`` (inf, nan, zero, negative, too long).
    """
    d = float(duration_s)
    if not (math.isfinite(d) and 0 < d <= MAX_DURATION_S):
        raise ConfigError(
            f"{what} = {duration_s!r}: expected a finite number of seconds > 0 and <= {MAX_DURATION_S:g}"
        )
    return d


@dataclass(frozen=True)
class RuntimeConfig:
    """Loop settings.

    Attributes:
        rate_hz: loop rate (sonars are read every cycle by default: six SRF08s at a 2 m range
            setting take 71 ms).
        deadline_slack: a cycle may end this fraction of a period late before it counts as missed.
        camera_every: read the depth camera every this many cycles (0 = never).
        sonar_every: read the sonar arrays every this many cycles (0 = never).
        stop_on_driver_fault: end the run after a driver fault (the chair is stopped either way).
        map_kind: map of the default perception stage: ``"probabilistic"`` (occupied, free and unknown
            per vertical interval) or ``"thesis"`` (accumulate only); see :class:`Perception`.
    """

    rate_hz: float = field(default=10.0, metadata=bounds(gt=0))
    deadline_slack: float = field(default=0.25, metadata=bounds(ge=0))
    camera_every: int = field(default=5, metadata=bounds(ge=0))
    sonar_every: int = field(default=1, metadata=bounds(ge=0))
    stop_on_driver_fault: bool = True
    map_kind: str = "probabilistic"

    def __post_init__(self) -> None:
        check_dataclass(self, "runtime")
        if self.map_kind not in MAP_KINDS:
            raise ConfigError(f"runtime.map_kind = {self.map_kind!r}: expected one of {', '.join(MAP_KINDS)}")

    @classmethod
    def from_dict(
        cls,
        data: Mapping[str, Any] | ConfigTable,
        source: ConfigSource | None = None,
        where: str = "runtime",
        **overrides: Any,
    ) -> RuntimeConfig:
        """From a TOML table (``where`` is its path, e.g. ``"runtime"``); ``overrides`` replace keys.

        Raises:
            ConfigError: an unknown key, a wrong type or a value out of range
                (``<file>:<line>: runtime.<key> = <value>: expected <what>``).
        """
        return load_dataclass(cls, data, source, where, **overrides)
