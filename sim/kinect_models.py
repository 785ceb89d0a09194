"""Kinect models: pinhole intrinsics, the v1 / v2 variants and their noise formulas (see :mod:`sim.kinect`).

Intrinsics follow ``fx = (W/2) / tan(hfov/2)``, ``fy = (H/2) / tan(vfov/2)``, principal point at the
image centre, pixel (u, v) sampled at its centre. Noise: Nguyen, Izadi & Lovell 2012 (Kinect v1) and
Fankhauser et al. 2015 (Kinect v2); z in metres, theta in radians, results in metres or pixels.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import numpy.typing as npt

from sim.errors import SimError
from sim.kinect_params import KINECT1_BASELINE_M, KINECT1_FOCAL_PX, KINECT1_SUBPIXEL, THETA_MAX

FloatArray = npt.NDArray[np.float64]


class KinectError(SimError, ValueError):
    """A Kinect model, pose or backend request is invalid."""


@dataclass(frozen=True)
class Intrinsics:
    """Pinhole intrinsics in pixels; pixel (u, v) is sampled at (u + 0.5, v + 0.5)."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float

    @classmethod
    def from_fov(cls, width: int, height: int, hfov_deg: float, vfov_deg: float) -> Intrinsics:
        if width <= 0 or height <= 0:
            raise KinectError(f"image size {width}x{height}: both must be positive")
        if not (0 < hfov_deg < 180 and 0 < vfov_deg < 180):
            raise KinectError(f"field of view {hfov_deg}x{vfov_deg} deg: each must be in (0, 180)")
        fx = 0.5 * width / math.tan(math.radians(hfov_deg) / 2)
        fy = 0.5 * height / math.tan(math.radians(vfov_deg) / 2)
        return cls(width, height, fx, fy, 0.5 * width, 0.5 * height)

    def rays(self) -> FloatArray:
        """(H, W, 3) ray directions in the ROS camera frame with unit forward (x) component."""
        r = np.empty((self.height, self.width, 3))
        r[..., 0] = 1.0
        r[..., 1] = self._ray_y(np.arange(self.width))[None, :]
        r[..., 2] = self._ray_z(np.arange(self.height))[:, None]
        return r

    def pixel_rays(self, pixels: Any) -> FloatArray:
        """``rays().reshape(-1, 3)[pixels]`` (N, 3), bit for bit, for flat pixel indices ``pixels`` (N,)
        (row-major, ``v * width + u``), without the (H, W, 3) table (50 MB in HD)."""
        v, u = np.divmod(np.asarray(pixels), self.width)
        r = np.empty((v.size, 3))
        r[:, 0] = 1.0
        r[:, 1] = self._ray_y(u)
        r[:, 2] = self._ray_z(v)
        return r

    def _ray_y(self, u: Any) -> FloatArray:
        """The y of the rays of columns ``u`` (left is +y)."""
        return np.asarray(-((u + 0.5 - self.cx) / self.fx), dtype=float)

    def _ray_z(self, v: Any) -> FloatArray:
        """The z of the rays of rows ``v`` (up is +z)."""
        return np.asarray(-((v + 0.5 - self.cy) / self.fy), dtype=float)


@dataclass(frozen=True)
class Registration:
    """The colour camera a Kinect v2 cloud is registered to (HD / qHD output)."""

    width: int
    height: int
    hfov_deg: float = 84.1
    vfov_deg: float = 53.8
    offset_m: tuple[float, float, float] = (0.0, 0.052, 0.0)  # colour camera origin in the depth frame

    @property
    def intrinsics(self) -> Intrinsics:
        return Intrinsics.from_fov(self.width, self.height, self.hfov_deg, self.vfov_deg)


@dataclass(frozen=True)
class KinectModel:
    """One Kinect variant: depth camera, range, noise model, optional registered output."""

    name: str
    width: int
    height: int
    hfov_deg: float
    vfov_deg: float
    min_range_m: float
    max_range_m: float
    noise_model: str  # "nguyen2012" | "fankhauser2015"
    quantization: str | None  # "disparity" | "mm" | None
    rate_hz: float = 30.0
    registration: Registration | None = None

    def __post_init__(self) -> None:
        if not 0 < self.min_range_m < self.max_range_m:
            raise KinectError(
                f"Kinect model {self.name!r}: range {self.min_range_m}-{self.max_range_m} m "
                "must satisfy 0 < min < max"
            )
        if self.noise_model not in ("nguyen2012", "fankhauser2015"):
            raise KinectError(f"Kinect model {self.name!r}: unknown noise model {self.noise_model!r}")
        if self.quantization not in (None, "disparity", "mm"):
            raise KinectError(f"Kinect model {self.name!r}: unknown quantization {self.quantization!r}")
        Intrinsics.from_fov(self.width, self.height, self.hfov_deg, self.vfov_deg)

    @property
    def intrinsics(self) -> Intrinsics:
        """Intrinsics of the depth camera (not of the registered output)."""
        return Intrinsics.from_fov(self.width, self.height, self.hfov_deg, self.vfov_deg)

    @property
    def output_shape(self) -> tuple[int, int]:
        """(H, W) of the organized cloud this model outputs."""
        if self.registration is not None:
            return (self.registration.height, self.registration.width)
        return (self.height, self.width)


_KINECT2 = KinectModel("kinect2", 512, 424, 70.0, 60.0, 0.5, 4.5, "fankhauser2015", "mm")

MODELS: dict[str, KinectModel] = {
    "kinect1": KinectModel("kinect1", 640, 480, 57.0, 43.0, 0.6, 4.0, "nguyen2012", "disparity"),
    "kinect2": _KINECT2,
    "kinect2-hd": replace(_KINECT2, name="kinect2-hd", registration=Registration(1920, 1080)),
    "kinect2-qhd": replace(_KINECT2, name="kinect2-qhd", registration=Registration(960, 540)),
}


def get_model(model: str | KinectModel) -> KinectModel:
    """A :class:`KinectModel` by name (``kinect1``, ``kinect2``, ``kinect2-hd``, ``kinect2-qhd``)."""
    if isinstance(model, KinectModel):
        return model
    try:
        return MODELS[model]
    except KeyError:
        raise KinectError(f"unknown Kinect model {model!r}; known: {', '.join(MODELS)}") from None


# --------------------------------------------------------------------------------------------
# noise models (pure functions; z in metres, theta in radians, results in metres or pixels)
# --------------------------------------------------------------------------------------------


# The angle is held at THETA_MAX (75 deg), short of the models' pole at 90 deg (sim.kinect_params).
def _angle_term(theta: Any) -> FloatArray:
    th = np.clip(np.asarray(theta, dtype=float), 0.0, THETA_MAX)
    return th**2 / (math.pi / 2 - th) ** 2


def nguyen2012_axial_sigma_m(z_m: Any, theta_rad: Any = 0.0) -> FloatArray:
    """Kinect v1 axial noise std (m): 0.0012 + 0.0019 (z - 0.4)^2 + 0.0001/sqrt(z) th^2/(pi/2 - th)^2."""
    z = np.asarray(z_m, dtype=float)
    return 0.0012 + 0.0019 * (z - 0.4) ** 2 + 0.0001 / np.sqrt(z) * _angle_term(theta_rad)


def nguyen2012_lateral_sigma_px(theta_rad: Any = 0.0) -> FloatArray:
    """Kinect v1 lateral noise std (px): 0.8 + 0.035 th/(pi/2 - th)."""
    th = np.clip(np.asarray(theta_rad, dtype=float), 0.0, THETA_MAX)
    return 0.8 + 0.035 * th / (math.pi / 2 - th)


def fankhauser2015_axial_sigma_m(z_m: Any, theta_rad: Any = 0.0) -> FloatArray:
    """Kinect v2 axial noise std (m): (1.5 - 0.5 z + 0.3 z^2 + 0.1 z^1.5 th^2/(pi/2 - th)^2) mm."""
    z = np.asarray(z_m, dtype=float)
    return 1e-3 * (1.5 - 0.5 * z + 0.3 * z**2 + 0.1 * z**1.5 * _angle_term(theta_rad))


def fankhauser2015_lateral_sigma_px(theta_rad: Any = 0.0) -> FloatArray:
    """Kinect v2 lateral noise std (px): 1.6, independent of distance and angle."""
    return np.full(np.shape(theta_rad), 1.6)


def quantize_depth(z: FloatArray, mode: str | None) -> FloatArray:
    """Round depth as the device's output does ("disparity": Kinect v1, "mm": Kinect v2, None: off)."""
    if mode is None:
        return z
    if mode == "mm":
        return np.round(z * 1000.0) / 1000.0
    if mode == "disparity":
        k = KINECT1_FOCAL_PX * KINECT1_BASELINE_M * KINECT1_SUBPIXEL  # z = k / d_steps
        with np.errstate(divide="ignore", invalid="ignore"):
            steps = np.round(k / z)
            return np.where(steps > 0, k / steps, np.nan)
    raise KinectError(f"unknown quantization {mode!r}")
