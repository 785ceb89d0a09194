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

The models and noise formulas are in :mod:`sim.kinect_models`, the renderers and the HD / qHD
registration in :mod:`sim.kinect_render`; this module holds the sensor and re-exports both.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from hw.interfaces import DepthFrame
from robchair.platform import frames
from sim.kinect_models import (
    MODELS,
    FloatArray,
    Intrinsics,
    KinectError,
    KinectModel,
    Registration,
    fankhauser2015_axial_sigma_m,
    fankhauser2015_lateral_sigma_px,
    get_model,
    nguyen2012_axial_sigma_m,
    nguyen2012_lateral_sigma_px,
    quantize_depth,
)
from sim.kinect_params import NOISE_CODES, QUANT_CODES
from sim.kinect_render import (
    CASTERS,
    DepthImage,
    linearize_depth_buffer,
    organized_normals,
    register_depth,
    render_pybullet,
    render_raycast,
)
from sim.raycast import MeshMirror, pose_matrix

__all__ = [
    "CASTERS",
    "MODELS",
    "DepthImage",
    "Intrinsics",
    "KinectCapture",
    "KinectError",
    "KinectModel",
    "KinectSim",
    "Registration",
    "fankhauser2015_axial_sigma_m",
    "fankhauser2015_lateral_sigma_px",
    "get_model",
    "linearize_depth_buffer",
    "nguyen2012_axial_sigma_m",
    "nguyen2012_lateral_sigma_px",
    "organized_normals",
    "quantize_depth",
    "register_depth",
    "render_pybullet",
    "render_raycast",
]


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
        g = rng or self.rng
        shape = (2, self.model.height, self.model.width)
        if type(g.bit_generator) is np.random.PCG64:
            # the same words as integers() over the full range (numpy returns PCG64's next 64-bit
            # output there), without its per-call range handling: 1.1 -> 0.9 ms CPU per frame
            return g.bit_generator.random_raw(size=shape)  # type: ignore[no-any-return]
        return g.integers(0, np.iinfo(np.uint64).max, size=shape, dtype=np.uint64, endpoint=True)

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
        # the raster caster's plain frame: one kernel from the triangles to the points (the same
        # points as render + finish, without the depth, normal and label images between them)
        fused = (
            not full
            and self.backend == "raycast"
            and self.caster == "raster"
            and (not self.noise or len(self._lateral_table) > 0)
        )
        t = pose_matrix(cam_pose) if fused else None
        img = None if fused else self.render(cam_pose, labels=full)
        h, w = (m.height, m.width) if img is None else img.depth.shape
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
        if t is not None:
            pts_raster = self._raster_points(t, bits)
            return DepthFrame(stamp_ns=int(stamp_ns), frame_id=self.frame_id, points=pts_raster)
        assert img is not None
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

    def _raster_points(self, t: FloatArray, bits: npt.NDArray[np.uint64]) -> npt.NDArray[np.float32]:
        """The plain frame's (h, w, 3) float32 points by :func:`sim._kinect_kernels.raster_capture`."""
        from sim._kinect_kernels import raster_capture

        mirror = self.mirror
        assert mirror is not None
        mirror.sync()
        m = self.model
        return raster_capture(  # type: ignore[no-any-return]
            mirror.tri_vertices,
            mirror.tri_faces,
            mirror.tri_geometry,
            np.ascontiguousarray(t[:3, :3]),
            np.ascontiguousarray(t[:3, 3]),
            self._ray_ax,
            self._ray_by,
            float(m.max_range_m * 1.5),
            bits,
            self._lateral_table,
            self._lateral_buckets,
            self.noise,
            NOISE_CODES[m.noise_model],
            QUANT_CODES[m.quantization],
            m.min_range_m,
            m.max_range_m,
        )

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
