"""Simulated Kinect v1 and v2 depth cameras: organized clouds with NaN holes, noise from the literature.

Models (SPEC section 3; erratum 5: the Kinect v2 minimum range is 0.5 m, not the thesis's 3 cm):

=============  =========  ===============  ==============  ==================================
model          image      field of view    range           noise
=============  =========  ===============  ==============  ==================================
kinect1        640x480    57 H x 43 V deg  0.6 - 4.0 m     Nguyen, Izadi, Lovell 2012
kinect2        512x424    70 H x 60 V deg  0.5 - 4.5 m     Fankhauser et al. 2015
kinect2-hd     1920x1080  84.1 x 53.8 deg  (the 512x424 depth, registered + up-sampled)
kinect2-qhd    960x540    84.1 x 53.8 deg  (likewise)
=============  =========  ===============  ==============  ==================================

Pinhole model shared by both backends: ``fx = (W/2) / tan(hfov/2)``, ``fy = (H/2) / tan(vfov/2)``,
principal point at the image centre, pixel (u, v) sampled at its centre ``(u + 0.5, v + 0.5)``
(the OpenGL convention, so the PyBullet renderer and the ray caster see the same rays). For the
Kinect v2 this gives fx = 365.6 px, close to the factory value of real devices (~365 px).

Output frame: the camera's ROS frame (REP-103): x forward (optical axis), y left, z up. A pixel's
point is ``depth * (1, -(u + 0.5 - cx)/fx, -(v + 0.5 - cy)/fy)``: ``depth`` is the distance along
the optical axis, as the real sensors report it. Pixels without a return, or with a depth outside
[min, max] range, are NaN (never 0, never the far plane).

Backends:

* ``"raycast"`` (default): one ray per pixel into the triangles of :class:`sim.raycast.MeshMirror`,
  found by image-space culling (``caster="raster"``, default) or by Embree (``caster="embree"``).
* ``"pybullet"``: PyBullet's ``getCameraImage`` with ``ER_TINY_RENDERER``; its non-linear depth
  buffer ``b`` is turned into metric depth by ``z = far * near / (far - (far - near) * b)``; the
  projection matrix is built from the same fx, fy, cx, cy. For cross-checking.

Noise (``noise=True``; a seeded ``numpy.random.Generator``; off gives the exact geometry):

* Kinect v1, Nguyen, Izadi & Lovell, "Modeling Kinect Sensor Noise for Improved 3D Reconstruction
  and Tracking", 3DIMPVT 2012: axial ``sigma_z(z, theta) = 0.0012 + 0.0019 (z - 0.4)^2
  + 0.0001 / sqrt(z) * theta^2 / (pi/2 - theta)^2`` metres (z in metres), lateral
  ``sigma_L(theta) = 0.8 + 0.035 theta / (pi/2 - theta)`` pixels. Plus the disparity quantisation of
  the structured-light sensor: depth steps of ``z^2 / (f b) * 1/8 px`` with f = 580 px, b = 7.5 cm
  (Khoshelham & Elberink 2012: ~7 cm steps at 5 m).
* Kinect v2, Fankhauser, Bloesch, Rodriguez, Kaestner, Hutter & Siegwart, "Kinect v2 for Mobile
  Robot Navigation: Evaluation and Modeling", ICAR 2015: axial ``sigma_z(z, theta) = 1.5 - 0.5 z
  + 0.3 z^2 + 0.1 z^(3/2) theta^2 / (pi/2 - theta)^2`` millimetres (z in metres), lateral
  ``sigma_L = 1.6`` pixels (indoor, no shadow). Depth is quantised to the driver's 1 mm.

Sources of the formulas: the papers' abstracts (titles, authors, and that both fit axial noise over
distance z and surface angle theta and lateral noise in pixels); the coefficients agree with several
independent implementations that cite the papers, including the mm unit of the v2 model and its
constant 1.6 px lateral term.
``theta`` is taken here as the angle between the surface normal and the viewing ray, held at 75 deg
for steeper surfaces (the models' angle terms have a pole at 90 deg and were not fitted that far;
at 85 deg the v2 model would give ~10 cm, scattering the silhouettes of round objects).

Random draws (seeded Generator, two 64-bit words per pixel, :meth:`KinectSim.noise_bits`): the
normal draws are made by inverse transform sampling from uniform words (Acklam's quantile, relative
error < 1.2e-9); the Kinect v2's rounded lateral offsets are read from the CDF of
``round(1.6 N(0, 1))`` directly. The same seed gives the same frames on any thread.

Lateral noise is applied the way it shows in real depth images: each pixel takes the depth (and
surface angle) found at a pixel offset drawn from N(0, sigma_L^2), rounded to the pixel grid, and
keeps its own ray, so edges jitter while planes stay planes.

Kinect v2 HD / qHD, as libfreenect2 / iai_kinect2 produce them: the 512x424 depth image (with its
noise) is registered to the colour camera (1920x1080, 84.1 x 53.8 deg, 5.2 cm to the left of the
depth camera in this model) by projecting every depth point into the colour image and splatting it
over its footprint with a z-buffer (the nearest surface wins). Each covered colour pixel gets the
point where its own ray meets the plane of the depth sample (position and normal), so planes stay
exact; colour pixels no depth sample covers (the colour camera is wider than the depth camera) stay
NaN. The output frame is then the colour camera's (``frame_id`` ends in ``_rgb``); use
:meth:`KinectSim.output_pose` / :meth:`KinectSim.to_world`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import numpy.typing as npt

from hw.interfaces import DepthFrame
from robchair import frames
from sim.errors import SimError
from sim.kinect_params import (
    KINECT1_BASELINE_M,
    KINECT1_FOCAL_PX,
    KINECT1_SUBPIXEL,
    NOISE_CODES,
    QUANT_CODES,
    THETA_MAX,
)
from sim.raycast import MeshMirror, pose_matrix

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
        u = (np.arange(self.width) + 0.5 - self.cx) / self.fx
        v = (np.arange(self.height) + 0.5 - self.cy) / self.fy
        r = np.empty((self.height, self.width, 3))
        r[..., 0] = 1.0
        r[..., 1] = -u[None, :]
        r[..., 2] = -v[:, None]
        return r


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


# --------------------------------------------------------------------------------------------
# backends: clean depth (H, W), normals in the camera frame (H, W, 3), (body, link) labels
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class DepthImage:
    """A clean rendered depth image: NaN where nothing was hit."""

    depth: FloatArray  # (H, W) metres along the optical axis
    normals: FloatArray  # (H, W, 3) unit normals in the camera frame (either orientation); NaN: no hit
    body: npt.NDArray[np.int64]  # (H, W) body unique id, -1 where no hit
    link: npt.NDArray[np.int64]  # (H, W) link index (-1 base), -1 where no hit


#: Ray casters of the ``"raycast"`` backend (see :func:`render_raycast`).
CASTERS = ("raster", "embree")


def render_raycast(
    mirror: MeshMirror,
    t_world_cam: FloatArray,
    intr: Intrinsics,
    far_m: float,
    *,
    rays: FloatArray | None = None,
    normals: bool = True,
    buffer: npt.NDArray[np.float32] | None = None,
    caster: str = "embree",
    labels: bool = True,
) -> DepthImage:
    """Depth image by ray casting into ``mirror`` (the caller syncs the mirror).

    ``rays`` may pass ``intr.rays()`` precomputed; ``normals=False`` skips the normals (NaN);
    ``buffer`` may pass a reusable (H*W, 6) float32 array for the rays handed to Embree.
    ``caster``: ``"embree"`` (Open3D's ``RaycastingScene``) or ``"raster"`` (the same rays tested
    against the mirror's triangles with image-space culling, :func:`sim._kinect_kernels.raster_depth`:
    the same geometry up to float rounding, several times faster for a camera's coherent rays).
    ``labels=False`` lets the raster caster skip the body and link images (1x1 placeholders then).
    The per-pixel work runs in compiled kernels that release the GIL, so a capture thread
    overlaps the simulation thread.
    """
    from sim._kinect_kernels import camera_ray_buffer, hits_to_image, raster_depth

    t = np.asarray(t_world_cam, dtype=np.float64)
    if t.shape != (4, 4) or not np.all(np.isfinite(t)):
        raise KinectError(f"camera pose must be a finite 4x4 matrix, got {t.tolist()}")
    if caster not in CASTERS:
        raise KinectError(f"caster {caster!r}: expected one of {', '.join(CASTERS)}")
    rays_cam = intr.rays() if rays is None else rays
    h, w = rays_cam.shape[:2]
    if caster == "raster":
        if mirror._scene is None:
            mirror.sync()
        ax = np.ascontiguousarray(rays_cam[0, :, 1])
        by = np.ascontiguousarray(rays_cam[:, 0, 2])
        depth, nc, body, link = raster_depth(
            mirror.tri_vertices,
            mirror.tri_faces,
            mirror.tri_geometry,
            mirror.keys,
            np.ascontiguousarray(t[:3, :3]),
            np.ascontiguousarray(t[:3, 3]),
            ax,
            by,
            float(far_m),
            bool(normals),
            bool(labels),
        )
        return DepthImage(depth, nc, body, link)
    if buffer is None or buffer.shape != (h * w, 6):
        buffer = np.empty((h * w, 6), dtype=np.float32)  # Embree works in float32 anyway
    r = np.ascontiguousarray(t[:3, :3])
    # forward component 1 in the camera frame -> t_hit is the depth
    camera_ray_buffer(rays_cam, r, np.ascontiguousarray(t[:3, 3]), buffer)
    t_hit, gid, nrm = mirror.cast_raw(buffer)
    depth, nc, body, link = hits_to_image(
        t_hit, gid, nrm, mirror.invalid_id, mirror.keys, r, float(far_m), h, w, bool(normals)
    )
    return DepthImage(depth, nc, body, link)


# OpenGL camera axes in the optical frame: x right (the same), y up = -y, z backwards = -z
_R_OPTICAL_GL = np.diag([1.0, -1.0, -1.0])


def _gl_view_matrix(t_world_cam: FloatArray) -> FloatArray:
    t_world_gl = frames.se3(t_world_cam[:3, :3] @ frames.R_LINK_OPTICAL @ _R_OPTICAL_GL, t_world_cam[:3, 3])
    return frames.invert(t_world_gl)


def _gl_projection(intr: Intrinsics, near: float, far: float) -> FloatArray:
    w, h = intr.width, intr.height
    return np.array(
        [
            [2 * intr.fx / w, 0.0, 1 - 2 * intr.cx / w, 0.0],
            [0.0, 2 * intr.fy / h, 2 * intr.cy / h - 1, 0.0],
            [0.0, 0.0, -(far + near) / (far - near), -2 * far * near / (far - near)],
            [0.0, 0.0, -1.0, 0.0],
        ]
    )


def linearize_depth_buffer(buf: Any, near: float, far: float) -> FloatArray:
    """Metric depth from an OpenGL-style depth buffer in [0, 1]; 1 (the far plane) becomes NaN."""
    b = np.asarray(buf, dtype=np.float64)
    z = far * near / (far - (far - near) * b)
    return np.where(b >= 1.0 - 1e-7, np.nan, z)


def organized_normals(points: FloatArray) -> FloatArray:
    """Unit normals of an organized cloud by central differences (NaN where undefined), facing the origin."""
    p = np.asarray(points, dtype=float)
    du = np.full_like(p, np.nan)
    dv = np.full_like(p, np.nan)
    du[:, 1:-1] = p[:, 2:] - p[:, :-2]
    dv[1:-1, :] = p[2:, :] - p[:-2, :]
    n = np.cross(du, dv)
    norm = np.linalg.norm(n, axis=-1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        n = n / norm
    flip = np.einsum("...k,...k->...", n, p) > 0
    n[flip] *= -1
    return n


def render_pybullet(
    client: int, t_world_cam: FloatArray, intr: Intrinsics, near_m: float, far_m: float
) -> DepthImage:
    """Depth image from PyBullet's CPU renderer (``ER_TINY_RENDERER``); normals estimated from depth."""
    import pybullet as p

    view = _gl_view_matrix(t_world_cam)
    # TinyRenderer samples pixel (u, v) of its top-down image at the continuous point (u, v + 1),
    # a pixel corner, not its centre (measured: with this shift the two backends agree to ~5 um
    # on planes; without it ~1 mm median, 2 cm at the 99th percentile on tilted surfaces)
    gl_intr = replace(intr, cx=intr.cx - 0.5, cy=intr.cy + 0.5)
    proj = _gl_projection(gl_intr, near_m, far_m)
    _, _, _, dbuf, seg = p.getCameraImage(
        intr.width,
        intr.height,
        viewMatrix=view.T.reshape(-1).tolist(),  # column-major, as OpenGL
        projectionMatrix=proj.T.reshape(-1).tolist(),
        renderer=p.ER_TINY_RENDERER,
        flags=p.ER_SEGMENTATION_MASK_OBJECT_AND_LINKINDEX,
        physicsClientId=client,
    )
    dbuf = np.asarray(dbuf, dtype=np.float64).reshape(intr.height, intr.width)
    seg = np.asarray(seg, dtype=np.int64).reshape(intr.height, intr.width)
    depth = linearize_depth_buffer(dbuf, near_m, far_m)
    # normals are estimated on the pixel-centre rays the caller uses
    pts = depth[..., None] * intr.rays()
    hit = seg >= 0
    body = np.where(hit, seg & ((1 << 24) - 1), -1)
    link = np.where(hit, (seg >> 24) - 1, -1)
    depth = np.where(hit, depth, np.nan)
    return DepthImage(depth, organized_normals(pts), body, link)


# --------------------------------------------------------------------------------------------
# HD / qHD registration
# --------------------------------------------------------------------------------------------


def register_depth(
    points_d: FloatArray,
    normals_d: FloatArray,
    intr_d: Intrinsics,
    reg: Registration,
) -> tuple[FloatArray, npt.NDArray[np.int64]]:
    """Register + up-sample a depth camera's organized cloud to the colour camera (z-buffer splat).

    Args:
        points_d: (h, w, 3) points in the depth camera frame, NaN where invalid.
        normals_d: (h, w, 3) surface normals of those points (depth camera frame).
        intr_d: depth camera intrinsics (for the footprint of one depth pixel).
        reg: the colour camera.

    Returns:
        ``(points_c, source)``: (H, W, 3) points in the colour camera frame (NaN where no depth
        sample covers the pixel) and (H, W) flat index of the depth pixel each came from (-1).
    """
    from sim._kinect_kernels import splat

    ic = reg.intrinsics
    flat = points_d.reshape(-1, 3)
    valid = np.flatnonzero(np.all(np.isfinite(flat), axis=1))
    pc = flat[valid] - np.asarray(reg.offset_m)  # colour camera has the depth camera's orientation
    x = pc[:, 0]
    front = x > 1e-6
    valid, pc, x = valid[front], pc[front], x[front]
    uc = ic.cx - ic.fx * pc[:, 1] / x  # continuous image coordinates (pixel centre at i + 0.5)
    vc = ic.cy - ic.fy * pc[:, 2] / x
    # one depth pixel spans (z_d / fx_d) metres; in the colour image that is fx_c * (z_d/fx_d) / x_c
    zd = flat[valid, 0]
    half_w = 0.5 * np.maximum(ic.fx / intr_d.fx, ic.fy / intr_d.fy) * zd / x * 1.05
    src_k = splat(uc, vc, x, half_w, ic.width, ic.height)
    src = np.where(src_k >= 0, valid[np.maximum(src_k, 0)], -1).reshape(ic.height, ic.width)
    out = np.full((ic.height, ic.width, 3), np.nan)
    hit = src >= 0
    s = src[hit]
    rays = ic.rays()[hit]
    p0 = flat[s] - np.asarray(reg.offset_m)
    n = normals_d.reshape(-1, 3)[s]
    # the point where the colour pixel's ray meets the sample's plane; keep the sample's depth
    # when the plane is unknown or seen edge-on (the intersection would run away)
    denom = np.einsum("ij,ij->i", n, rays)
    with np.errstate(invalid="ignore", divide="ignore"):
        t = np.einsum("ij,ij->i", n, p0) / denom
    ok = np.isfinite(t) & (np.abs(denom) > 0.2) & (np.abs(t - p0[:, 0]) < 0.05 * p0[:, 0])
    t = np.where(ok, t, p0[:, 0])
    out[hit] = t[:, None] * rays
    return out, src


# --------------------------------------------------------------------------------------------
# noise + quantisation + range cut, fused (one pass over the image instead of ~20 numpy passes)
# --------------------------------------------------------------------------------------------


def _rounded_normal_cdf(noise_model: str, half_width: int = 16) -> FloatArray:
    """CDF table of a lateral offset ``round(N(0, 1) * sigma_L)`` for j = -J..J when ``sigma_L`` is
    constant (Kinect v2: 1.6 px): ``Phi((j + 0.5) / sigma_L)``; empty when it varies per pixel.

    J = 16 reaches 10 sigma, far below the 2^-32 resolution of the uniforms it is compared with.
    """
    if noise_model != "fankhauser2015":
        return np.zeros(0)
    sigma = float(fankhauser2015_lateral_sigma_px(0.0))
    j = np.arange(-half_width, half_width + 1)
    return np.array([0.5 * math.erfc(-(k + 0.5) / sigma / math.sqrt(2.0)) for k in j])


def _offset_buckets(table: FloatArray) -> npt.NDArray[np.int8]:
    """Per 16-bit bucket of the 32-bit uniforms: the offset ``table`` gives every value in it, or
    127 where a CDF step falls inside the bucket (see :func:`sim._kinect_kernels.finish`)."""
    if len(table) == 0:
        return np.zeros(0, dtype=np.int8)
    b = np.arange(1 << 16, dtype=np.float64)
    half = len(table) // 2

    def offset(k: FloatArray) -> npt.NDArray[np.int64]:
        i = np.searchsorted(table, (k + 0.5) / 2.0**32, side="right")
        return np.minimum(i, len(table) - 1) - half

    lo, hi = offset(b * 65536.0), offset(b * 65536.0 + 65535.0)
    return np.where(lo == hi, lo, 127).astype(np.int8)


# --------------------------------------------------------------------------------------------
# the sensor
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class KinectCapture:
    """Everything one capture produced: the frame plus labels for segmentation and checks."""

    frame: DepthFrame
    depth: FloatArray  # (h, w) depth of the native depth image after noise (NaN invalid)
    body: npt.NDArray[np.int64]  # (H, W) body id behind each output pixel (-1)
    link: npt.NDArray[np.int64]  # (H, W) link index behind each output pixel (-1)


class KinectSim:
    """A simulated Kinect over a PyBullet world.

    Args:
        client: PyBullet physics client id.
        model: model name or :class:`KinectModel` (see :data:`MODELS`).
        backend: ``"raycast"`` (Open3D/Embree over a :class:`MeshMirror`) or ``"pybullet"``.
        noise: add the model's axial + lateral noise and quantisation.
        rng: ``numpy.random.Generator`` (or an int seed) for the noise; ``None`` means seed 0.
        mirror: a shared :class:`MeshMirror` (for the raycast backend); one is made if ``None``.
        exclude_bodies: bodies the camera must not see: left out of a mirror made here (seen through);
            the PyBullet backend can only blank their pixels (NaN), it cannot see through them.
        frame_id: ``frame_id`` of the frames (default ``kinect_link``; ``kinect_rgb`` for HD/qHD).
        near_m: near clipping plane of the PyBullet renderer.
        caster: how the ``"raycast"`` backend finds each pixel's first hit: ``"raster"`` (default;
            the pixel rays tested against the mirror's triangles with image-space culling) or
            ``"embree"`` (Open3D's ``RaycastingScene``); see :func:`render_raycast`. They agree to
            a few micrometres (a test checks it); the raster caster is several times faster.

    ``capture(pose)`` takes the camera's world pose (4x4, or (position, quaternion xyzw)) in the
    ROS convention (x forward) and returns a :class:`hw.interfaces.DepthFrame`.
    """

    def __init__(
        self,
        client: int,
        model: str | KinectModel = "kinect2",
        *,
        backend: str = "raycast",
        noise: bool = True,
        rng: np.random.Generator | int | None = None,
        mirror: MeshMirror | None = None,
        exclude_bodies: Any = (),
        frame_id: str | None = None,
        near_m: float = 0.05,
        caster: str = "raster",
    ) -> None:
        self.client = int(client)
        self.model = get_model(model)
        if backend not in ("raycast", "pybullet"):
            raise KinectError(f"backend {backend!r}: expected 'raycast' or 'pybullet'")
        self.backend = backend
        if caster not in CASTERS:
            raise KinectError(f"caster {caster!r}: expected one of {', '.join(CASTERS)}")
        self.caster = caster
        self.noise = bool(noise)
        self.rng = (
            rng if isinstance(rng, np.random.Generator) else np.random.default_rng(0 if rng is None else rng)
        )
        self.mirror = mirror
        if backend == "raycast" and self.mirror is None:
            self.mirror = MeshMirror(self.client, exclude_bodies=exclude_bodies)
        self.exclude_bodies = {int(b) for b in exclude_bodies}
        reg = self.model.registration
        self.frame_id = frame_id or ("kinect_rgb" if reg is not None else "kinect_link")
        if not 0 < near_m < self.model.min_range_m:
            raise KinectError(f"near_m={near_m}: must be in (0, min range {self.model.min_range_m})")
        self.near_m = near_m
        self._rays = self.model.intrinsics.rays()
        # the rays' y and z components per column and row (the x component is 1)
        self._ray_ax = np.ascontiguousarray(self._rays[0, :, 1])
        self._ray_by = np.ascontiguousarray(self._rays[:, 0, 2])
        self._lateral_table = _rounded_normal_cdf(self.model.noise_model)
        self._lateral_buckets = _offset_buckets(self._lateral_table)

    # ---- frames -----------------------------------------------------------------------------

    def output_pose(self, cam_pose: Any) -> FloatArray:
        """World pose of the frame the clouds are expressed in (the colour camera for HD/qHD)."""
        t = pose_matrix(cam_pose)
        reg = self.model.registration
        if reg is None:
            return t
        return t @ frames.se3(translation=reg.offset_m)

    def to_world(self, points: Any, cam_pose: Any) -> FloatArray:
        """Transform an organized (H, W, 3) or (N, 3) cloud of this camera to the world frame (NaN kept)."""
        t = self.output_pose(cam_pose)
        pts = np.asarray(points, dtype=float)
        return pts @ t[:3, :3].T + t[:3, 3]

    # ---- capture ----------------------------------------------------------------------------

    def render(self, cam_pose: Any, *, labels: bool = True) -> DepthImage:
        """The clean depth image of the depth camera (no noise, no range cut) at ``cam_pose``.

        ``labels=False``: the body and link images may be 1x1 placeholders (raster caster).
        """
        t = pose_matrix(cam_pose)
        intr = self.model.intrinsics
        far = self.model.max_range_m * 1.5
        if self.backend == "raycast":
            assert self.mirror is not None
            self.mirror.sync()
            need_normals = self.noise or self.model.registration is not None
            return render_raycast(
                self.mirror,
                t,
                intr,
                far,
                rays=self._rays,
                normals=need_normals,
                caster=self.caster,
                labels=labels,
            )
        img = render_pybullet(self.client, t, intr, self.near_m, far)
        if self.exclude_bodies:
            drop = np.isin(img.body, list(self.exclude_bodies))
            img = DepthImage(
                np.where(drop, np.nan, img.depth),
                np.where(drop[..., None], np.nan, img.normals),
                np.where(drop, -1, img.body),
                np.where(drop, -1, img.link),
            )
        return img

    def capture_full(
        self,
        cam_pose: Any,
        *,
        stamp_ns: int = 0,
        rng: np.random.Generator | None = None,
        noise_bits: npt.NDArray[np.uint64] | None = None,
    ) -> KinectCapture:
        """Capture one frame and keep the per-pixel (body, link) labels (see :class:`KinectCapture`)."""
        return self._capture(cam_pose, stamp_ns, rng, noise_bits, labels=True)  # type: ignore[return-value]

    def noise_bits(self, rng: np.random.Generator | None = None) -> npt.NDArray[np.uint64] | None:
        """The random words one noisy capture consumes (None when the noise is off).

        Drawing them apart from :meth:`capture` (``noise_bits=``) lets frames be captured on several
        threads while the generator is still used in frame order: the frames are then the same as
        captured one after the other. Two uniform 64-bit words per pixel: lateral u and v (32 bits
        each), axial (53 bits); the kernel turns them into normal draws (see
        :func:`sim._kinect_kernels.finish`).
        """
        if not self.noise:
            return None
        return (rng or self.rng).integers(
            0,
            np.iinfo(np.uint64).max,
            size=(2, self.model.height, self.model.width),
            dtype=np.uint64,
            endpoint=True,
        )

    def _capture(
        self,
        cam_pose: Any,
        stamp_ns: int,
        rng: np.random.Generator | None,
        noise_bits: npt.NDArray[np.uint64] | None,
        *,
        labels: bool,
    ) -> KinectCapture | DepthFrame:
        """The capture; with ``labels=False`` only the frame (the kernel skips depth and labels)."""
        m = self.model
        # HD / qHD registration needs each pixel's source index, which comes with the labels
        full = labels or m.registration is not None
        img = self.render(cam_pose, labels=full)
        h, w = img.depth.shape
        bits: Any
        if not self.noise:
            bits = np.zeros((2, 1, 1), dtype=np.uint64)
        elif noise_bits is None:
            bits = self.noise_bits(rng)
        else:
            bits = np.asarray(noise_bits)
            if bits.shape != (2, h, w) or bits.dtype != np.uint64:
                raise KinectError(
                    f"noise_bits of shape {bits.shape}, {bits.dtype}: expected (2, {h}, {w}) uint64"
                )
        from sim._kinect_kernels import finish

        z, src, pts, body, link = finish(
            img.depth,
            img.normals,
            img.body,
            img.link,
            self._ray_ax,
            self._ray_by,
            bits,
            self._lateral_table,
            self._lateral_buckets,
            self.noise,
            NOISE_CODES[m.noise_model],
            QUANT_CODES[m.quantization],
            m.min_range_m,
            m.max_range_m,
            full,
        )
        if m.registration is not None:
            normals = img.normals.reshape(-1, 3)[src]
            hd_pts, hd_src = register_depth(pts.astype(np.float64), normals, m.intrinsics, m.registration)
            pts = hd_pts.astype(np.float32)
            flat_b, flat_l = body.reshape(-1), link.reshape(-1)
            body = np.where(hd_src >= 0, flat_b[np.maximum(hd_src, 0)], -1)
            link = np.where(hd_src >= 0, flat_l[np.maximum(hd_src, 0)], -1)
        frame = DepthFrame(stamp_ns=int(stamp_ns), frame_id=self.frame_id, points=pts)
        return KinectCapture(frame, z, body, link) if labels else frame

    def capture(
        self,
        cam_pose: Any,
        *,
        stamp_ns: int = 0,
        rng: np.random.Generator | None = None,
        noise_bits: npt.NDArray[np.uint64] | None = None,
    ) -> DepthFrame:
        """One :class:`DepthFrame` (organized float32 cloud, NaN = no return) at world pose ``cam_pose``.

        ``noise_bits``: the frame's random words drawn beforehand by :meth:`noise_bits` (else they
        are drawn here from ``rng`` or the camera's generator).
        """
        return self._capture(cam_pose, stamp_ns, rng, noise_bits, labels=False)  # type: ignore[return-value]
