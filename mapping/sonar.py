"""Sonar arrays as the thesis uses them: detection model, five-zone fusion, servo rule, cone -> points.

Pure numpy; nothing here talks to hardware. The pieces, in the order data flows through them:

1. **Detection model of one sonar** (thesis Appendix A). A flat obstacle was moved toward the
   sonar's axis at forward distances ``x`` of 2-100 cm and the lateral offset ``y`` where it was first
   detected was marked; least squares gave the two boundaries, in centimetres::

       top    y = -0.0031 x^2 + 1.2082 x - 14.2762      (8.0.1)
       bottom y =  0.0001 x^2 - 0.8483 x +  7.7197      (8.0.2)

   ``x`` points along the sonar's axis and ``y`` to its left (REP-103: +y = counter-clockwise seen
   from above), so the top curve bounds the left side of the beam and the bottom curve the right side.
   The beam is not symmetric because the SRF08 has separate send and receive transducers.

   A range reading ``d`` is the straight-line distance to the echoing point, so the half-aperture of
   the beam at range ``d`` is the bearing at which the circle of radius ``d`` crosses a boundary:
   ``phi_left(d)`` solves ``d sin(phi) = top(d cos(phi))`` and ``phi_right(d)`` solves
   ``d sin(phi) = -bottom(d cos(phi))`` (bisection, vectorised). The model is valid from 15 cm to 1 m:

   * **Over 1 m** readings are rejected (the thesis: "only accept readings under one metre"; the cone
     is too wide there to place anything). Fusion treats them like "no echo" and reports them.
   * **Under 15 cm** the thesis switches to the parallel-obstacle measurement, which gives a *wider*
     area than the regression but is not printed (the regression itself closes at ~10.9 cm, where the
     two curves cross). We substitute, on each side, the widest half-aperture the model reaches
     anywhere in 15 cm - 1 m (``WIDE_HALF_APERTURE_DEG``). That is wider than the regression at 15 cm,
     as the thesis says the true short-range area is, and errs toward placing a near obstacle in too
     large a zone rather than too small a one. It is a stated substitution, not thesis data.

2. **Zones of an array** (thesis 5.2, Fig. 5.3). Three sonars, sonar 1 (left) at ``+outer``, sonar 2
   at 0 and sonar 3 (right) at ``-outer`` (``outer`` = 30 deg). At range ``d`` sonar k covers the
   bearing interval ``S_k = [a_k - phi_right, a_k + phi_left]``. The five zones are the overlap
   regions, with ``L = phi_left(d)``, ``R = phi_right(d)``, ``o = outer``::

       zone 1 = S1 minus (S2 u S3) = [max(o - R, L),     o + L]
       zone 2 = S1 n S2 minus S3   = [max(o - R, L - o), L]
       zone 3 = S1 n S2 n S3       = [o - R,             L - o]
       zone 4 = S2 n S3 minus S1   = [-R,                min(L - o, o - R)]
       zone 5 = S3 minus (S1 u S2) = [-o - R,            min(L - o, -R)]

   A zone's start angle ``alpha`` is its lower (clockwise-most) bearing and its aperture ``theta`` is
   its width (0 when the interval is empty). With ``o = 30`` the outer four zones are 30 deg wide and
   zone 3 is ``L + R - 60`` wide (9.5 deg at 0.5 m, 14.7 deg at 1 m: the smallest zone, as the
   thesis says). Zone 3 is empty where ``L + R < 60``, i.e. from 15 cm to 31 cm, where the
   regression's beam is narrow (and zones 2 and 4 are empty at exactly 15 cm). :func:`zone_tables`
   tabulates ``alpha`` and ``theta`` for every integer centimetre 0..100, like the thesis's look-up
   tables indexed by ``d`` in cm.

3. **Five-zone fusion** (:func:`fuse_array`, thesis 5.2). ``d`` = the smallest valid reading; a sonar
   *agrees* when its reading is within ``threshold`` of ``d``. The set of agreeing sonars names the
   zone: {1} -> 1, {1, 2} -> 2, {1, 2, 3} -> 3, {2, 3} -> 4, {3} -> 5. The sets {2} and {1, 3} are
   not zones (a single target seen by sonar 2 is always seen by sonar 1 or 3 once ``L + R >= 60``);
   they come from missed specular echoes or two targets, and give ``zone=None`` with the obstacle
   kept in the hull of the agreeing sonars' beams, never dropped.

4. **Servo rule** (:func:`servo_command_deg`): turn toward the fused bearing so the target ends up in
   zone 3, the narrowest zone.

5. **Known failure** (thesis 5.2): inside a cylinder every sonar reads the radius, all three agree
   and zone 3 is chosen although the obstacle surrounds the array. :func:`fuse_array` does exactly
   that (it cannot know better from one reading). :class:`CylinderCheck` adds what one reading
   cannot: a single target (or a wall, whose nearest point acts as one) can stay in zone 3 only while
   the array turns by less than zone 3's aperture; zone 3 at an unchanged distance over a wider turn
   flags ``cylinder_suspected`` and widens the interval to the whole array coverage, i.e. "all five
   zones should be considered".

6. **Cone -> point cloud** (:func:`cone_points`, thesis Fig. 5.7), exactly as printed; see there.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import numpy.typing as npt

from mapping._sonar_one import cone_points_fast, one_bearing_deg
from mapping.errors import SonarModelError

FloatArray = npt.NDArray[np.float64]

#: Coefficients (a, b, c) of y = a x^2 + b x + c, centimetres, thesis (8.0.1): left side of the beam.
TOP_BOUNDARY_COEFFS_CM = (-0.0031, 1.2082, -14.2762)
#: Coefficients (a, b, c) of (8.0.2): right side of the beam.
BOTTOM_BOUNDARY_COEFFS_CM = (0.0001, -0.8483, 7.7197)
#: The regression is used from this range up (thesis Appendix A).
MODEL_MIN_RANGE_CM = 15.0
#: Readings over this range are rejected (thesis 5.4 / Appendix A).
MODEL_MAX_RANGE_CM = 100.0
#: Angle of the outer sonars from the middle one (thesis 5.2).
OUTER_SONAR_DEG = 30.0
#: Number of zones of a three-sonar array.
N_ZONES = 5


def top_boundary_cm(x_cm: npt.ArrayLike) -> FloatArray:
    """Left boundary of one sonar's detection area, thesis (8.0.1).

    Args:
        x_cm: forward distance(s) along the sonar axis, cm.

    Returns:
        Lateral offset(s) ``y`` in cm (positive = left of the axis).
    """
    a, b, c = TOP_BOUNDARY_COEFFS_CM
    x = np.asarray(x_cm, dtype=np.float64)
    return np.asarray(a * x * x + b * x + c, dtype=np.float64)


def bottom_boundary_cm(x_cm: npt.ArrayLike) -> FloatArray:
    """Right boundary of one sonar's detection area, thesis (8.0.2) (negative = right of the axis)."""
    a, b, c = BOTTOM_BOUNDARY_COEFFS_CM
    x = np.asarray(x_cm, dtype=np.float64)
    return np.asarray(a * x * x + b * x + c, dtype=np.float64)


def _crossing_bearing_deg(d_cm: FloatArray, side: str) -> FloatArray:
    """Bearing (deg, >= 0) where the circle of radius ``d_cm`` leaves the detection area on ``side``.

    Inside the area on the left means ``d sin(phi) <= top(d cos(phi))``; the difference is strictly
    decreasing in phi on 0..89 deg for d in 15..100 cm (the circle rises, the boundary falls or rises
    more slowly), so a bisection of 60 halvings pins the root to ~1e-16 deg.
    """
    lo = np.zeros_like(d_cm)
    hi = np.full_like(d_cm, 89.0)

    def inside(phi_deg: FloatArray) -> npt.NDArray[np.bool_]:
        phi = np.radians(phi_deg)
        x = d_cm * np.cos(phi)
        y = d_cm * np.sin(phi)
        if side == "left":
            return np.asarray(y <= top_boundary_cm(x))
        return np.asarray(y <= -bottom_boundary_cm(x))

    for _ in range(60):
        mid = 0.5 * (lo + hi)
        ok = inside(mid)
        lo = np.where(ok, mid, lo)
        hi = np.where(ok, hi, mid)
    return 0.5 * (lo + hi)


#: Half-apertures of single ranges already solved, ``{d_cm: (left, right)}``. Sonar readings come in
#: whole centimetres, so a run meets few distinct ranges; the bisection costs ~10 ms per range.
_SOLVED: dict[float, tuple[FloatArray, FloatArray]] = {}
_SOLVED_MAX = 65536


def _model_half_apertures_deg(d_cm: FloatArray) -> tuple[FloatArray, FloatArray]:
    if d_cm.shape != (1,):
        return _crossing_bearing_deg(d_cm, "left"), _crossing_bearing_deg(d_cm, "right")
    key = float(d_cm[0])  # one range: the same bisection on floats (mapping._sonar_one), once per value
    hit = _SOLVED.get(key)
    if hit is None:
        if len(_SOLVED) >= _SOLVED_MAX:
            _SOLVED.clear()
        hit = (np.array([one_bearing_deg(key, "left")]), np.array([one_bearing_deg(key, "right")]))
        for a in hit:
            a.setflags(write=False)
        _SOLVED[key] = hit
    return hit[0], hit[1]


def _widest_half_apertures_deg() -> tuple[float, float]:
    d = np.linspace(MODEL_MIN_RANGE_CM, MODEL_MAX_RANGE_CM, 851)
    left, right = _model_half_apertures_deg(d)
    return float(left.max()), float(right.max())


#: Half-apertures (left, right) used under 15 cm: the widest the model reaches in 15 cm - 1 m.
WIDE_HALF_APERTURE_DEG: tuple[float, float] = _widest_half_apertures_deg()


def half_apertures_deg(range_cm: npt.ArrayLike) -> tuple[FloatArray, FloatArray]:
    """Left and right half-apertures of one sonar's beam at the given range(s).

    Args:
        range_cm: range reading(s) in cm, 0 < d <= 100.

    Returns:
        ``(left_deg, right_deg)``, both >= 0: the beam covers bearings ``[-right_deg, +left_deg]``
        around the sonar axis. Under 15 cm the constant :data:`WIDE_HALF_APERTURE_DEG` is used
        (see the module docstring for why).

    Raises:
        SonarModelError: a range is not finite, not positive, or over 100 cm.
    """
    d = np.atleast_1d(np.asarray(range_cm, dtype=np.float64))
    bad = ~np.isfinite(d) | (d <= 0.0) | (d > MODEL_MAX_RANGE_CM)
    if bad.any():
        raise SonarModelError(
            f"range_cm={d[bad][0]!r} is outside the detection model's domain (0, {MODEL_MAX_RANGE_CM}] cm"
        )
    short = d < MODEL_MIN_RANGE_CM
    left, right = _model_half_apertures_deg(np.where(short, MODEL_MIN_RANGE_CM, d))
    left = np.where(short, WIDE_HALF_APERTURE_DEG[0], left)
    right = np.where(short, WIDE_HALF_APERTURE_DEG[1], right)
    shape = np.shape(range_cm)
    return left.reshape(shape), right.reshape(shape)


def in_detection_area(range_cm: npt.ArrayLike, bearing_deg: npt.ArrayLike) -> npt.NDArray[np.bool_]:
    """Whether a point at (range, bearing) from one sonar is inside its detection area.

    Args:
        range_cm: straight-line distance(s) from the sonar, cm (any value; over 100 cm or <= 0 is False).
        bearing_deg: bearing(s) from the sonar axis, deg, counter-clockwise positive.

    Returns:
        Boolean array of the broadcast shape.
    """
    d, b = np.broadcast_arrays(
        np.asarray(range_cm, dtype=np.float64), np.asarray(bearing_deg, dtype=np.float64)
    )
    ok = np.isfinite(d) & np.isfinite(b) & (d > 0.0) & (d <= MODEL_MAX_RANGE_CM)
    out = np.zeros(d.shape, dtype=bool)
    if ok.any():
        left, right = half_apertures_deg(d[ok])
        out[ok] = (b[ok] <= left) & (b[ok] >= -right)
    return out


def zone_intervals_deg(range_cm: npt.ArrayLike, outer_deg: float = OUTER_SONAR_DEG) -> FloatArray:
    """Bearing intervals of the five zones (module docstring, item 2) at the given range(s).

    Returns:
        Array of shape ``(..., 5, 2)``: ``[..., k-1, 0]`` the start angle ``alpha`` and
        ``[..., k-1, 1]`` the end angle of zone k, in the array frame (deg, CCW positive, 0 = sonar
        2's axis). An empty zone has end < start.
    """
    if not (math.isfinite(outer_deg) and 0.0 < outer_deg < 90.0):
        raise SonarModelError(f"outer_deg={outer_deg!r} must be in (0, 90) degrees")
    L, R = half_apertures_deg(range_cm)
    o = outer_deg
    lo = np.stack([np.maximum(o - R, L), np.maximum(o - R, L - o), o - R, -R, -o - R], axis=-1)
    hi = np.stack([o + L, L, L - o, np.minimum(L - o, o - R), np.minimum(L - o, -R)], axis=-1)
    return np.stack([lo, hi], axis=-1)


def sonar_intervals_deg(range_cm: float, outer_deg: float = OUTER_SONAR_DEG) -> FloatArray:
    """Bearing intervals (3, 2) covered by sonars 1, 2, 3 at ``range_cm`` (array frame, deg)."""
    L, R = half_apertures_deg(range_cm)
    axes = np.array([outer_deg, 0.0, -outer_deg])
    return np.stack([axes - float(R), axes + float(L)], axis=-1)


@dataclass(frozen=True)
class ZoneTables:
    """Look-up tables of zone start angle and aperture per integer centimetre (thesis 5.4).

    Attributes:
        outer_deg: angle of the outer sonars from the middle one.
        alpha_deg: (5, 101) start angle of zone k at range ``d`` cm in ``[k-1, d]``.
        theta_deg: (5, 101) aperture of zone k (0 where the zone is empty).
    """

    outer_deg: float
    alpha_deg: FloatArray
    theta_deg: FloatArray

    def lookup(self, zone: int, range_m: float) -> tuple[float, float]:
        """``(alpha_deg, theta_deg)`` of ``zone`` at ``range_m``, indexed by the rounded range in cm.

        Raises:
            SonarModelError: zone not in 1..5, or the range is not in (0, 1] m.
        """
        if zone not in range(1, N_ZONES + 1):
            raise SonarModelError(f"zone={zone!r} must be one of 1..5")
        if not (math.isfinite(range_m) and 0.0 < range_m <= MODEL_MAX_RANGE_CM / 100.0):
            raise SonarModelError(f"range_m={range_m!r} must be in (0, 1] m for the zone tables")
        d_cm = round(range_m * 100.0)
        return float(self.alpha_deg[zone - 1, d_cm]), float(self.theta_deg[zone - 1, d_cm])

    @functools.cached_property
    def _fused(self) -> dict[Any, FusionResult]:  # fusion results built with these tables (fuse_array)
        return {}


def zone_tables(outer_deg: float = OUTER_SONAR_DEG) -> ZoneTables:
    """Build the zone look-up tables for d = 0..100 cm (row 0 uses the short-range beam like 1-14 cm)."""
    d = np.arange(0, int(MODEL_MAX_RANGE_CM) + 1, dtype=np.float64)
    d[0] = 1.0  # 0 cm is not a reading; give it the short-range beam like its neighbours
    iv = zone_intervals_deg(d, outer_deg)  # (101, 5, 2)
    alpha = iv[..., 0].T.copy()
    theta = np.maximum(iv[..., 1] - iv[..., 0], 0.0).T.copy()
    alpha.setflags(write=False)
    theta.setflags(write=False)
    return ZoneTables(outer_deg=float(outer_deg), alpha_deg=alpha, theta_deg=theta)


_DEFAULT_TABLES: ZoneTables | None = None


def default_zone_tables() -> ZoneTables:
    """The tables for the thesis array (outer sonars at +-30 deg), built once."""
    global _DEFAULT_TABLES
    if _DEFAULT_TABLES is None:
        _DEFAULT_TABLES = zone_tables(OUTER_SONAR_DEG)
    return _DEFAULT_TABLES


#: Agreeing-sonar sets (sonar 1, 2, 3) -> zone number, thesis 5.2.
_ZONE_OF_AGREEMENT: dict[tuple[bool, bool, bool], int] = {
    (True, False, False): 1,
    (True, True, False): 2,
    (True, True, True): 3,
    (False, True, True): 4,
    (False, False, True): 5,
}


@dataclass(frozen=True)
class FusionResult:
    """Outcome of fusing one array's three readings.

    Attributes:
        zone: 1..5, or None when no sonar has a valid reading or the agreeing sonars form no zone.
        distance_m: smallest valid reading (NaN when there is none).
        alpha_deg: start angle of the bearing interval holding the obstacle (array frame, CCW).
        theta_deg: width of that interval (0 with no obstacle).
        agreeing: which sonars read within ``threshold`` of ``distance_m``.
        rejected: which sonars read a range over 1 m (rejected, thesis 5.4).
        missing: which sonars gave no echo (NaN, +inf or 0).
        consistent: the interval is the zone's table entry. False when the zone is empty at this
            range in the detection model, or when no zone applies; the interval is then the hull of
            the agreeing sonars' beams (conservative: wider, never dropped).
        cylinder_suspected: set by :class:`CylinderCheck`, never by :func:`fuse_array` alone.
    """

    zone: int | None
    distance_m: float
    alpha_deg: float
    theta_deg: float
    agreeing: tuple[bool, bool, bool]
    rejected: tuple[bool, bool, bool]
    missing: tuple[bool, bool, bool]
    consistent: bool
    cylinder_suspected: bool = False

    @property
    def has_obstacle(self) -> bool:
        return math.isfinite(self.distance_m)

    @property
    def bearing_deg(self) -> float:
        """Centre of the interval (NaN with no obstacle)."""
        if not self.has_obstacle:
            return math.nan
        return self.alpha_deg + 0.5 * self.theta_deg


def _hull(intervals: FloatArray) -> tuple[float, float]:
    lo = float(intervals[:, 0].min())
    hi = float(intervals[:, 1].max())
    return lo, hi - lo


def fuse_array(
    r1_m: float,
    r2_m: float,
    r3_m: float,
    threshold_m: float = 0.03,
    tables: ZoneTables | None = None,
) -> FusionResult:
    """Five-zone fusion of the readings of sonars 1 (left), 2 (middle), 3 (right), thesis 5.2.

    Args:
        r1_m, r2_m, r3_m: ranges in metres. NaN, +inf or 0 mean "no echo"; over 1 m is rejected.
        threshold_m: two readings agree when they differ by at most this much.
        tables: zone tables (default: :func:`default_zone_tables`).

    Returns:
        A :class:`FusionResult`. The obstacle is at ``distance_m`` somewhere in
        ``[alpha_deg, alpha_deg + theta_deg]``.

    Raises:
        SonarModelError: a reading is negative or -inf, or the threshold is not a finite value >= 0.
    """
    if not (math.isfinite(threshold_m) and threshold_m >= 0.0):
        raise SonarModelError(f"threshold_m={threshold_m!r} must be a finite value >= 0")
    tables = default_zone_tables() if tables is None else tables
    # three readings: plain float arithmetic (the same IEEE operations as on a numpy array, without
    # its per-call overhead; the fusion runs for every array reading)
    a, b, c = float(r1_m), float(r2_m), float(r3_m)
    for k, v in ((1, a), (2, b), (3, c)):
        if v < 0.0 or v == -math.inf:
            raise SonarModelError(f"r{k}_m={v!r} is negative: a range reading must be >= 0 or NaN")
    isfinite, top = math.isfinite, MODEL_MAX_RANGE_CM / 100.0
    mis = (not isfinite(a) or a == 0.0, not isfinite(b) or b == 0.0, not isfinite(c) or c == 0.0)
    rej = (not mis[0] and a > top, not mis[1] and b > top, not mis[2] and c > top)
    va, vb, vc = not (mis[0] or rej[0]), not (mis[1] or rej[1]), not (mis[2] or rej[2])
    if not (va or vb or vc):
        return FusionResult(None, math.nan, 0.0, 0.0, (False, False, False), rej, mis, consistent=False)
    d = min(v for v, ok in ((a, va), (b, vb), (c, vc)) if ok)
    # inclusive "+- threshold"; 1 nm slack so 0.52 - 0.49 counts as 3 cm despite float rounding
    near = threshold_m + 1e-9
    key = (va and abs(a - d) <= near, vb and abs(b - d) <= near, vc and abs(c - d) <= near)
    # the result depends on (d, key, rej, mis) and the tables only: built once each (readings in cm)
    memo, fused = (d, key, rej, mis), tables._fused
    hit = fused.get(memo)
    if hit is None:
        if len(fused) >= 65536:
            fused.clear()
        hit = fused[memo] = _fused_interval(d, key, rej, mis, tables)
    return hit


def _fused_interval(d: float, key: Any, rej: Any, mis: Any, tables: ZoneTables) -> FusionResult:
    zone = _ZONE_OF_AGREEMENT.get(key)
    if zone is not None:
        alpha, theta = tables.lookup(zone, d)
        if theta > 0.0:
            return FusionResult(zone, d, alpha, theta, key, rej, mis, consistent=True)
    # no usable zone interval: keep the obstacle anywhere the agreeing sonars could have seen it
    # (for {1, 3} that may be two targets, one in each outer beam, so not their intersection)
    alpha, theta = _hull(sonar_intervals_deg(d * 100.0, tables.outer_deg)[np.array(key)])
    return FusionResult(zone, d, alpha, theta, key, rej, mis, consistent=False)


def servo_command_deg(
    result: FusionResult,
    current_deg: float,
    gain: float = 1.0,
    max_step_deg: float | None = None,
    limits_deg: tuple[float, float] = (0.0, 180.0),
) -> float:
    """Servo rule (thesis 5.2): turn toward the nearest measurement so the target sits in zone 3.

    Convention: a larger servo angle turns the array counter-clockwise (to the left), the same sense
    as bearings; 90 deg faces the array's mount forward.

    Args:
        result: the latest fusion.
        current_deg: current servo angle.
        gain: fraction of the bearing error corrected per step (1 = jump onto the target).
        max_step_deg: optional bound on one step's size.
        limits_deg: the servo's travel; the command is clamped into it.

    Returns:
        The new servo angle. With no obstacle, the current angle (clamped): the array holds still.
    """
    if not math.isfinite(current_deg):
        raise SonarModelError(f"current_deg={current_deg!r} must be finite")
    lo, hi = limits_deg
    if not result.has_obstacle:
        return float(min(max(current_deg, lo), hi))
    step = gain * result.bearing_deg
    if max_step_deg is not None:
        step = max(-max_step_deg, min(max_step_deg, step))
    return float(min(max(current_deg + step, lo), hi))


class CylinderCheck:
    """Flags the thesis's cylinder failure from a run of zone-3 fusions over a turning array.

    A single target at distance ``d`` stays in zone 3 only while the array heading changes by less
    than zone 3's aperture at ``d``. If zone 3 keeps being reported at the same distance (within
    ``threshold_m``) while the heading spans more than that aperture plus ``margin_deg``, the
    obstacle must cover more than zone 3 (e.g. it surrounds the array): the result is flagged and its
    interval widened to the array's whole coverage at ``d``, the "consider all five zones" the thesis
    asks for. It needs the array to turn (servo sweep or chair rotation); it cannot act on one reading.
    """

    def __init__(self, threshold_m: float = 0.03, margin_deg: float = 2.0, tables: ZoneTables | None = None):
        self.threshold_m = threshold_m
        self.margin_deg = margin_deg
        self.tables = default_zone_tables() if tables is None else tables
        self._run_distance: float | None = None
        self._min_heading = math.inf
        self._max_heading = -math.inf

    def reset(self) -> None:
        self._run_distance = None
        self._min_heading = math.inf
        self._max_heading = -math.inf

    def update(self, result: FusionResult, heading_deg: float) -> FusionResult:
        """Feed one fusion and the array heading (servo angle plus robot yaw, deg) it was taken at."""
        if result.zone != 3:
            self.reset()
            return result
        if self._run_distance is None or abs(result.distance_m - self._run_distance) > self.threshold_m:
            self.reset()
            self._run_distance = result.distance_m
        self._min_heading = min(self._min_heading, heading_deg)
        self._max_heading = max(self._max_heading, heading_deg)
        _, zone3_theta = self.tables.lookup(3, result.distance_m)
        if self._max_heading - self._min_heading <= zone3_theta + self.margin_deg:
            return result
        alpha, theta = _hull(sonar_intervals_deg(result.distance_m * 100.0, self.tables.outer_deg))
        return replace(result, alpha_deg=alpha, theta_deg=theta, consistent=False, cylinder_suspected=True)


def cone_points(range_m: float, theta_deg: float, alpha_deg: float, ppc: int = 40) -> FloatArray:
    """Points of a zone at range ``range_m``, thesis Fig. 5.7 exactly as printed (SPEC section 3).

    For ``i = 0, 1, ...`` while ``i < theta/2`` (degrees) and ``j = 0 .. ppc-1``::

        auxX = d sin(90 - theta/2 - i)
        auxY = d cos(90 - theta/2 - i) sin(360 j / ppc)
        Z    = d cos(90 - theta/2 - i) cos(360 j / ppc)
        X    = cos(alpha + theta/2 - i) auxX - sin(alpha + theta/2 - i) auxY
        Y    = sin(alpha + theta/2 - i) auxX + cos(alpha + theta/2 - i) auxY

    Geometry (used by the tests): every point is at distance ``d`` from the origin; ring ``i`` is a
    circle of ``ppc`` points at angle ``beta_i = theta/2 + i`` from the axis at bearing
    ``gamma_i = alpha + theta/2 - i`` in the horizontal plane. Ring 0 spans exactly the zone
    ``[alpha, alpha + theta]``. As printed, later rings grow while their axis moves clockwise, so
    the cloud also covers bearings down to ``alpha - 2 i_max`` (about ``alpha - theta``) on the
    clockwise side. The algorithm is kept as printed (SPEC section 3 asks for Fig. 5.7 verbatim;
    SPEC erratum 7 records the spill).

    Args:
        range_m: range ``d`` in metres (points come out in metres).
        theta_deg: zone aperture (deg); 0 gives no points.
        alpha_deg: zone start angle (deg, array frame, CCW from sonar 2's axis).
        ppc: points per circle, >= 1.

    Returns:
        ``(n_rings * ppc, 3)`` float64 points in the array frame (x forward along sonar 2, y left, z up).

    Raises:
        SonarModelError: a non-finite or negative argument, or ppc < 1.
    """
    for name, v in (("range_m", range_m), ("theta_deg", theta_deg), ("alpha_deg", alpha_deg)):
        if not math.isfinite(v):
            raise SonarModelError(f"{name}={v!r} must be finite")
    if range_m < 0.0 or theta_deg < 0.0:
        raise SonarModelError(f"range_m={range_m!r} and theta_deg={theta_deg!r} must be >= 0")
    if int(ppc) != ppc or ppc < 1:
        raise SonarModelError(f"ppc={ppc!r} must be an integer >= 1")
    i = np.arange(0.0, theta_deg / 2.0)[:, None]  # 0, 1, ... while i < theta/2
    j = np.arange(int(ppc), dtype=np.float64)[None, :]
    elev = np.radians(90.0 - theta_deg / 2.0 - i)
    spin = np.radians(360.0 * j / ppc)
    rot = np.radians(alpha_deg + theta_deg / 2.0 - i)
    aux_x = range_m * np.sin(elev) * np.ones_like(spin)
    aux_y = range_m * np.cos(elev) * np.sin(spin)
    z = range_m * np.cos(elev) * np.cos(spin)
    x = np.cos(rot) * aux_x - np.sin(rot) * aux_y
    y = np.sin(rot) * aux_x + np.cos(rot) * aux_y
    return np.stack([x.ravel(), y.ravel(), z.ravel()], axis=-1)


#: Clouds of :func:`fusion_points` already built, ``{(range, theta, alpha, ppc): points}`` (read-only).
#: Readings come in whole centimetres and the zone intervals from tables indexed by them, so a run
#: meets few distinct cones; each is built once by :func:`cone_points` (the same array it returns).
_CONES: dict[tuple[float, float, float, int], FloatArray] = {}
_CONES_MAX = 4096


def fusion_points(result: FusionResult, ppc: int = 40) -> FloatArray:
    """The point cloud of a fusion (array frame, metres): Fig. 5.7 for its interval, or (0, 3).

    The array is read-only and may be shared with other calls of the same cone (copy it to change it).
    """
    if not result.has_obstacle or result.theta_deg <= 0.0:
        return np.empty((0, 3), dtype=np.float64)
    key = (float(result.distance_m), float(result.theta_deg), float(result.alpha_deg), int(ppc))
    pts = _CONES.get(key)
    if pts is None:
        pts = cone_points_fast(result.distance_m, result.theta_deg, result.alpha_deg, int(ppc))
        pts.setflags(write=False)
        if len(_CONES) >= _CONES_MAX:
            _CONES.clear()
        _CONES[key] = pts
    return pts


def array_points(
    ranges_m: Any,
    threshold_m: float = 0.03,
    ppc: int = 40,
    tables: ZoneTables | None = None,
) -> tuple[FusionResult, FloatArray]:
    """Fuse three readings and turn them into points in one call: ``(fusion, (N, 3) points)``."""
    r1, r2, r3 = (float(v) for v in ranges_m)
    res = fuse_array(r1, r2, r3, threshold_m, tables)
    return res, fusion_points(res, ppc)


def beam_points(range_m: float, alpha_deg: float, theta_deg: float, half_elev_deg: float) -> FloatArray:
    """Points at ``range_m`` filling a beam's cross-section: bearings ``[alpha, alpha + theta]`` and
    elevations ``[-half_elev, +half_elev]`` on a 1-degree lattice, both ends included (array frame, m).

    The free space in front of a reading is the solid beam; the Fig. 5.7 rings of :func:`cone_points`
    (kept as printed for the occupied points) leave the beam's axis unsampled when the aperture is wide.

    Returns:
        ``(N, 3)`` float64 points at distance ``range_m`` from the origin.
    """
    nb = max(2, math.ceil(theta_deg) + 1)
    ne = max(2, math.ceil(2.0 * half_elev_deg) + 1)
    b = np.radians(np.linspace(alpha_deg, alpha_deg + theta_deg, nb))[:, None]
    e = np.radians(np.linspace(-half_elev_deg, half_elev_deg, ne))[None, :]
    xyz = np.stack([np.cos(e) * np.cos(b), np.cos(e) * np.sin(b), np.sin(e) * np.ones_like(b)], axis=-1)
    return np.asarray(range_m * xyz.reshape(-1, 3), dtype=np.float64)
