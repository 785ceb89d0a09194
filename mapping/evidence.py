"""Parameters and results of the probabilistic VHV map (:mod:`mapping.probabilistic`).

:class:`EvidenceParams` holds the evidence model (OctoMap's defaults for the probabilities, the
near-surface rule's distances); :class:`EvidenceStats` reports one insertion; :class:`EvidenceIntervals`
is the map's content as a structure of arrays.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from mapping.errors import MappingError
from mapping.vhv import InsertStats


def _logit(p: float) -> float:
    return math.log(p / (1.0 - p))


@dataclass(frozen=True)
class EvidenceParams:
    """Parameters of the evidence update (OctoMap's defaults for the probabilities).

    Args:
        prob_hit: probability of occupation after one hit on an unknown interval (0.5 < p < 1).
        prob_miss: probability after one pass of free space (0 < p < 0.5).
        clamp_min: lower clamping bound of the probability (keeps free space revisable).
        clamp_max: upper clamping bound (keeps a moving obstacle clearable within a few frames).
        occupied_threshold: an interval with ``p >= occupied_threshold`` is occupied.
        free_threshold: an interval with ``p < free_threshold`` is free (between both: unknown).
        height_resolution: lattice step of interval bounds along the kept axis, metres.
        surface_half_thickness: half thickness of the slab a structure's hit covers, metres; None =
            half the cell size.
        surface_margin: how much each per-cell run of free space is shrunk at both ends (near-surface
            rule), metres; None = one cell size.
        gap_fill: free runs of one cell separated by at most this much are joined before the shrink,
            metres. Neighbouring fans leave holes of a centimetre or two where the cloud's sampling
            left a cell without points; a surface is thicker than that, and a surface the frame hits is
            cut out of the free space anyway.
        max_table_bytes: memory for the per-frame (cell, height bin) bit table; beyond it the free bins
            grow coarser (whole multiples of ``height_resolution``).
        dynamic_decay_s: seconds after its last hit at which a *dynamic* occupied interval is forgotten
            (becomes unknown, not free); None: nothing decays. An interval is dynamic when a hit lands
            where the map knew free space (DUFOMap's "void" rule: something moved in): a person who
            walks out of the sensor's view leaves no trail, since no later ray would clear it. Static
            surfaces are never seen free, so they do not decay. Needs insertion stamps (``stamp=``).
        dynamic_max_dwell_s: only dynamic intervals hit for at most this long (from their first
            dynamic hit to their last) decay; None: any. A person walking passes a cell within a second
            or two, while a static surface that looked free at first (seen at grazing incidence, where a
            fan's hull crosses it) keeps being hit as long as it is in view.
        dynamic_void_probability: a stored piece counts as known free for that rule when its
            probability is below this; None: ``free_threshold``. Lower values ask for more passes of
            free space (one pass gives ``prob_miss``), so that range noise at a surface's edge (a cell
            seen free now and hit next frame) does not make the surface dynamic.

    Raises:
        MappingError: a value out of its range.
    """

    prob_hit: float = 0.7
    prob_miss: float = 0.4
    clamp_min: float = 0.1192
    clamp_max: float = 0.971
    occupied_threshold: float = 0.5
    free_threshold: float = 0.5
    height_resolution: float = 0.01
    surface_half_thickness: float | None = None
    surface_margin: float | None = None
    gap_fill: float = 0.02
    max_table_bytes: int = 64 << 20
    dynamic_decay_s: float | None = None
    dynamic_void_probability: float | None = None
    dynamic_max_dwell_s: float | None = None

    def __post_init__(self) -> None:
        def prob(name: str, lo: float, hi: float) -> None:
            v = getattr(self, name)
            if not (isinstance(v, int | float) and math.isfinite(v) and lo < v < hi):
                raise MappingError(f"EvidenceParams.{name}={v!r}: expected a probability in ({lo}, {hi})")

        prob("prob_hit", 0.5, 1.0)
        prob("prob_miss", 0.0, 0.5)
        prob("clamp_min", 0.0, 1.0)
        prob("clamp_max", 0.0, 1.0)
        prob("occupied_threshold", 0.0, 1.0)
        prob("free_threshold", 0.0, 1.0)
        if not self.clamp_min < self.clamp_max:
            raise MappingError(
                f"EvidenceParams clamp_min={self.clamp_min!r} >= clamp_max={self.clamp_max!r}: "
                "expected min < max"
            )
        if self.free_threshold > self.occupied_threshold:
            raise MappingError(
                f"EvidenceParams free_threshold={self.free_threshold!r} > occupied_threshold="
                f"{self.occupied_threshold!r}: expected free <= occupied"
            )
        r = self.height_resolution
        if not (isinstance(r, int | float) and math.isfinite(r) and r > 0):
            raise MappingError(f"EvidenceParams.height_resolution={r!r}: expected metres > 0")
        for name in ("surface_half_thickness", "surface_margin", "gap_fill"):
            v = getattr(self, name)
            if v is not None and not (isinstance(v, int | float) and math.isfinite(v) and v >= 0):
                raise MappingError(f"EvidenceParams.{name}={v!r}: expected metres >= 0 or None")
        d = self.dynamic_decay_s
        if d is not None and not (isinstance(d, int | float) and math.isfinite(d) and d > 0):
            raise MappingError(f"EvidenceParams.dynamic_decay_s={d!r}: expected seconds > 0 or None")
        w = self.dynamic_max_dwell_s
        if w is not None and not (isinstance(w, int | float) and math.isfinite(w) and w >= 0):
            raise MappingError(f"EvidenceParams.dynamic_max_dwell_s={w!r}: expected seconds >= 0 or None")
        if self.dynamic_void_probability is not None:
            prob("dynamic_void_probability", 0.0, 1.0)
        if int(self.max_table_bytes) < 1 << 16:
            raise MappingError(f"EvidenceParams.max_table_bytes={self.max_table_bytes!r}: expected >= 65536")

    @property
    def log_odds(self) -> dict[str, float]:
        """The parameters as log-odds: hit, miss, min, max, occupied, free."""
        return {
            "hit": _logit(self.prob_hit),
            "miss": _logit(self.prob_miss),
            "min": _logit(self.clamp_min),
            "max": _logit(self.clamp_max),
            "occupied": _logit(self.occupied_threshold),
            "free": _logit(self.free_threshold),
            "void": _logit(
                self.free_threshold
                if self.dynamic_void_probability is None
                else self.dynamic_void_probability
            ),
        }


@dataclass(frozen=True)
class EvidenceStats(InsertStats):
    """What one insertion did: :class:`mapping.vhv.InsertStats` plus the evidence it produced.

    Attributes:
        free_intervals: free intervals of the frame after merging (per cell, disjoint).
        occupied_slabs: occupied slabs of the frame (per cell, disjoint).
        fan_passages: (structure, cell) passages the fans marked.
        cells_updated: cells whose intervals were rewritten.
        intervals: intervals stored in the map after the frame.
        truncated_points: points beyond ``max_range`` (free space up to the range, no hit).
        decayed: dynamic occupied intervals forgotten before this frame's update
            (:attr:`EvidenceParams.dynamic_decay_s`).
    """

    free_intervals: int = 0
    occupied_slabs: int = 0
    fan_passages: int = 0
    cells_updated: int = 0
    intervals: int = 0
    truncated_points: int = 0
    decayed: int = 0


@dataclass(frozen=True, eq=False)
class EvidenceIntervals:
    """Every stored interval as a structure of arrays, sorted by cell then bottom.

    Attributes:
        i, j: cell indices (int32).
        bottom, top: interval bounds along the kept axis, metres (float64); ``[bottom, top)``.
        log_odds: clamped log-odds of occupation (float32).
        probability: ``1 / (1 + exp(-log_odds))`` (float64).
        occupied: ``probability >= occupied_threshold``.
        free: ``probability < free_threshold``.
    """

    i: NDArray[np.int32]
    j: NDArray[np.int32]
    bottom: NDArray[np.float64]
    top: NDArray[np.float64]
    log_odds: NDArray[np.float32]
    probability: NDArray[np.float64] = field(repr=False)
    occupied: NDArray[np.bool_] = field(repr=False)
    free: NDArray[np.bool_] = field(repr=False)

    def __len__(self) -> int:
        return int(self.i.shape[0])
