"""Deterministic synthetic point clouds of an indoor scene, as a Kinect v2 on the chair would see it.

Used by the mapping benchmark (a 1920x1080 organized cloud with ~10 % NaN, like the thesis's HD
frames) and as the sample input of ``robchair map`` before the simulator exists. The scene is ray-cast
analytically (no PyBullet): a room (floor, walls, ceiling), a table on four legs, a closet, and a
person-like cylinder. World frame REP-103 (x forward, y left, z up, metres); the camera sits at
``(0, 0, camera_height)`` looking along +x, pitched down.

All randomness (depth noise, invalid pixels) comes from the ``numpy.random.Generator`` passed in.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from mapping.errors import MappingError

# Kinect v2 colour camera (the HD registered cloud): ~84 x 54 deg field of view at 1920 x 1080.
_FX_HD = 1066.0
_MIN_RANGE = 0.5  # m, documented minimum (SPEC erratum 5)
_MAX_RANGE = 4.5  # m

# Axis-aligned boxes (x0, y0, z0, x1, y1, z1) standing in the room.
_BOXES = np.array(
    [
        [1.80, 0.30, 0.72, 2.60, 1.30, 0.76],  # table top
        [1.82, 0.32, 0.00, 1.87, 0.37, 0.72],  # legs
        [2.53, 0.32, 0.00, 2.58, 0.37, 0.72],
        [1.82, 1.23, 0.00, 1.87, 1.28, 0.72],
        [2.53, 1.23, 0.00, 2.58, 1.28, 0.72],
        [3.60, -2.40, 0.00, 4.20, -1.40, 2.00],  # closet against the front-right corner
    ]
)
_ROOM = (-1.0, -2.5, 0.0, 4.2, 2.5, 2.6)  # the camera is inside this box
_PERSON = (2.4, -0.7, 0.20, 1.70)  # cylinder: centre x, y, radius, height


def _camera_rays(height: int, width: int, pitch_rad: float) -> NDArray[np.float64]:
    """Unit-free world directions (H, W, 3) of the pixels of a pinhole camera looking along +x."""
    fx = _FX_HD * width / 1920.0
    cx, cy = (width - 1) / 2.0, (height - 1) / 2.0
    xn = (np.arange(width) - cx) / fx
    yn = (np.arange(height) - cy) / fx
    d = np.empty((height, width, 3))
    d[..., 0] = 1.0  # optical z -> world x
    d[..., 1] = -xn[None, :]  # optical x (right) -> world -y
    d[..., 2] = -yn[:, None]  # optical y (down) -> world -z
    c, s = math.cos(pitch_rad), math.sin(pitch_rad)
    x, z = d[..., 0].copy(), d[..., 2].copy()
    d[..., 0] = x * c + z * s  # rotation about y: positive pitch looks down
    d[..., 2] = -x * s + z * c
    return d


def _hit_boxes(
    o: NDArray[np.float64],
    d: NDArray[np.float64],
    t: NDArray[np.float64],
    boxes: NDArray[np.float64] = _BOXES,
) -> None:
    """Lower ``t`` (ray parameter of the nearest hit so far) where a ray hits a box first (slab test)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / d
        for box in boxes:
            t0 = (box[:3] - o) * inv
            t1 = (box[3:] - o) * inv
            tn = np.nanmax(np.minimum(t0, t1), axis=-1)
            tf = np.nanmin(np.maximum(t0, t1), axis=-1)
            hit = (tf >= tn) & (tn > 0.0) & (tn < t)
            t[hit] = tn[hit]


def _hit_room(o: NDArray[np.float64], d: NDArray[np.float64]) -> NDArray[np.float64]:
    """Ray parameter where each ray leaves the room (hits a wall, the floor or the ceiling)."""
    lo, hi = np.array(_ROOM[:3]), np.array(_ROOM[3:])
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(d > 0, (hi - o) / d, np.where(d < 0, (lo - o) / d, np.inf))
    return np.asarray(t.min(axis=-1))


def _hit_person(o: NDArray[np.float64], d: NDArray[np.float64], t: NDArray[np.float64]) -> None:
    """Lower ``t`` where a ray hits the side of the person-like vertical cylinder first."""
    px, py, r, hgt = _PERSON
    dx, dy = d[..., 0], d[..., 1]
    ox, oy = o[0] - px, o[1] - py
    a = dx * dx + dy * dy
    b = 2.0 * (ox * dx + oy * dy)
    c = ox * ox + oy * oy - r * r
    disc = b * b - 4 * a * c
    with np.errstate(invalid="ignore", divide="ignore"):
        tc = (-b - np.sqrt(disc)) / (2 * a)
    z = o[2] + tc * d[..., 2]
    hit = (disc >= 0) & (tc > 0) & (tc < t) & (z >= 0.0) & (z <= hgt)
    t[hit] = tc[hit]


def render_scene(
    rng: np.random.Generator,
    height: int,
    width: int,
    nan_fraction: float = 0.1,
    camera_height: float = 1.0,
    pitch_deg: float = 10.0,
) -> NDArray[np.float32]:
    """Ray-cast the indoor scene into an organized (H, W, 3) float32 cloud in the world frame.

    Args:
        rng: source of the depth noise and of the invalid pixels.
        height, width: image size in pixels (the field of view stays the Kinect v2 HD one).
        nan_fraction: target fraction of invalid (NaN) pixels, out-of-range pixels included.
        camera_height: camera height above the floor in metres.
        pitch_deg: downward tilt of the camera in degrees.

    Raises:
        MappingError: non-positive size or a fraction outside [0, 1].
    """
    if int(height) < 1 or int(width) < 1:
        raise MappingError(f"synthetic cloud size {height}x{width}: expected positive pixel counts")
    if not 0.0 <= float(nan_fraction) <= 1.0:
        raise MappingError(f"synthetic cloud nan_fraction={nan_fraction!r}: expected a value in [0, 1]")
    o = np.array([0.0, 0.0, float(camera_height)])
    d = _camera_rays(int(height), int(width), math.radians(pitch_deg))
    t = _hit_room(o, d)
    _hit_boxes(o, d, t)
    _hit_person(o, d, t)
    # Depth along the optical axis decides validity, like the sensor's range gate.
    axis = np.array([math.cos(math.radians(pitch_deg)), 0.0, -math.sin(math.radians(pitch_deg))])
    depth = t * (d @ axis)
    # Kinect v2 depth noise grows roughly with the square of the distance (about 1.5 mm at 1 m).
    sigma = 0.0015 * np.maximum(depth, _MIN_RANGE) ** 2
    t = t * (1.0 + rng.standard_normal(t.shape) * sigma / np.maximum(depth, 1e-9))
    invalid = (depth < _MIN_RANGE) | (depth > _MAX_RANGE) | ~np.isfinite(t)
    n = invalid.size
    extra = (float(nan_fraction) * n - np.count_nonzero(invalid)) / max(n - np.count_nonzero(invalid), 1)
    if extra > 0:
        invalid |= rng.random(invalid.shape) < extra
    pts = (o + d * t[..., None]).astype(np.float32)
    pts[invalid] = np.nan
    return pts


def kinect_hd_like_cloud(
    rng: np.random.Generator, height: int = 1080, width: int = 1920, nan_fraction: float = 0.1
) -> NDArray[np.float32]:
    """An organized Kinect-v2-HD-like cloud (H, W, 3) float32 of a room seen from ~1 m height.

    Floor, walls, a table, a closet and a person-like cylinder; about ``nan_fraction`` of the pixels
    are NaN (out of range or dropped at random). Deterministic for a given generator state.
    """
    return render_scene(rng, height, width, nan_fraction=nan_fraction)


def small_sample_cloud(rng: np.random.Generator) -> NDArray[np.float32]:
    """A few 10k finite points (N, 3) float32 of the same scene (a 256 x 144 frame without its NaNs)."""
    pts = render_scene(rng, 144, 256, nan_fraction=0.05).reshape(-1, 3)
    return np.ascontiguousarray(pts[np.isfinite(pts).all(axis=1)])


def render_boxes(
    rng: np.random.Generator | None,
    boxes: NDArray[np.float64],
    origin: tuple[float, float, float],
    height: int = 120,
    width: int = 160,
    yaw_deg: float = 0.0,
    pitch_deg: float = 10.0,
    max_range: float = _MAX_RANGE,
    floor: bool = True,
) -> NDArray[np.float32]:
    """Ray-cast axis-aligned boxes (and the floor ``z = 0``) from a depth camera at ``origin``.

    The camera has the Kinect v2 HD field of view at any pixel count, looks along +x turned by
    ``yaw_deg`` (counter-clockwise) and pitched down by ``pitch_deg``. Used to build moving-obstacle
    sequences (e.g. a walker crossing the view at 30 Hz) for the evidence map's tests and benchmark.

    Args:
        rng: depth noise source (Kinect-v2-like, growing with the square of the range); None: no noise.
        boxes: ``(K, 6)`` boxes ``(x0, y0, z0, x1, y1, z1)``, metres.
        origin: camera position, metres.
        height, width: pixels.
        yaw_deg, pitch_deg: heading and downward tilt, degrees.
        max_range: depth beyond which a pixel is NaN (no return), metres.
        floor: add the infinite floor plane ``z = 0``.

    Returns:
        ``(height, width, 3)`` float32 world points, NaN where nothing is hit within range.

    Raises:
        MappingError: a bad size, box array or range.
    """
    if int(height) < 1 or int(width) < 1:
        raise MappingError(f"render_boxes size {height}x{width}: expected positive pixel counts")
    b = np.asarray(boxes, dtype=np.float64).reshape(-1, 6)
    if not np.all(np.isfinite(b)) or np.any(b[:, 3:] < b[:, :3]):
        raise MappingError(
            "render_boxes boxes: expected finite (x0, y0, z0, x1, y1, z1) rows with min <= max"
        )
    if not (math.isfinite(max_range) and max_range > 0):
        raise MappingError(f"render_boxes max_range={max_range!r}: expected metres > 0")
    o = np.asarray(origin, dtype=np.float64).reshape(3)
    d = _camera_rays(int(height), int(width), math.radians(pitch_deg))
    c, s_ = math.cos(math.radians(yaw_deg)), math.sin(math.radians(yaw_deg))
    x, y = d[..., 0].copy(), d[..., 1].copy()
    d[..., 0] = c * x - s_ * y
    d[..., 1] = s_ * x + c * y
    t = np.full(d.shape[:2], np.inf)
    if floor:
        with np.errstate(divide="ignore", invalid="ignore"):
            tf = -o[2] / d[..., 2]
        t = np.where((d[..., 2] < 0) & (tf > 0), tf, np.inf)
    _hit_boxes(o, d, t, b)
    dist = t * np.linalg.norm(d, axis=-1)
    valid = dist <= max_range
    if rng is not None:
        sigma = 0.0015 * np.maximum(dist, _MIN_RANGE) ** 2
        noise = rng.standard_normal(t.shape)
        t = np.where(valid, t * (1.0 + noise * sigma / np.maximum(dist, 1e-9)), 0.0)
    t = np.where(valid, t, 0.0)
    pts = (o + d * t[..., None]).astype(np.float32)
    pts[~valid] = np.nan
    return pts
