"""Simulated ultrasonic rangers (Devantech SRF08 / SRF04) and three-sonar arrays on a servo.

One sonar is a bundle of rays cast into :class:`sim.raycast.MeshMirror`, shaped by the measured
detection area of thesis Appendix A (SPEC section 3) through ``mapping.sonar.half_apertures_deg``:
at range ``d`` the beam covers bearings ``[-right(d), +left(d)]`` around the sonar axis (the beam is
not symmetric: separate send and receive transducers). The thesis measured the area in the
horizontal plane only; vertically the beam is taken as symmetric with the mean of the two
half-apertures, and a hit is inside the beam when ``(bearing / h)^2 + (elevation / v)^2 <= 1`` with
``h`` the side's half-aperture and ``v`` the vertical one. The regression is fitted up to 1 m; beyond
that the beam keeps the apertures it has at 1 m (the sensor still echoes up to its range limit; the
fusion in ``mapping.sonar`` rejects readings over 1 m, the simulation does not pre-empt that).

Echo rule: ultrasound reflects specularly off smooth surfaces, so a ray only produces an echo when
the surface faces the sonar: the angle between the surface normal and the reversed ray must be at
most ``max_incidence_deg``. Without this every sonar mounted 30-50 cm above the floor would read the
floor at the bottom edge of its cone. The default, 40 deg, sits between two facts: Appendix A
detected a flat obstacle *facing along the sonar's axis* anywhere in the measured area, i.e. up to
~37 deg off the axis (so the limit must be above that, or the measured cone would shrink to the
limit for flat things), and a level sonar sees the floor at >= 52.6 deg incidence (90 deg minus the
widest vertical half-aperture), which leaves ~12 deg of margin for the chair pitching. A large wall
turned more than ~77 deg from the axis (40 + 37) gives no echo, the classic specular blind spot.
The reading is the
*first* echo: the smallest accepted distance, rounded to whole centimetres as the SRF08 reports
``range_cm``; NaN when there is no echo or the echo is outside [min, max] range (the ROS Range
convention: such values are not measurements).

Timing: the SRF08 needs 65 ms per ranging at its full range (~15 Hz), the SRF04 about 45 ms (~22 Hz,
SPEC table). The simulation returns the reading at once; :attr:`SonarModel.ranging_time_s` tells a
scheduler how often it may ask.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from hw.interfaces import RangeReading, SonarArrayReading
from robchair.platform import frames
from robchair.platform.spec import default_spec
from sim.errors import SimError
from sim.raycast import MeshMirror, pose_matrix

FloatArray = npt.NDArray[np.float64]

#: The beam's caster when none is named: the image-space raster over the mirror's triangles
#: (:mod:`sim._sonar_raster`), Embree's echoes to its float32 rounding (tests/sim/test_sonar_raster.py).
#: A test that replays readings recorded with Embree sets this to ``"embree"``.
DEFAULT_CASTER = "raster"


class SonarSimError(SimError, ValueError):
    """A simulated sonar was configured or queried with invalid values."""


@dataclass(frozen=True)
class SonarModel:
    """Range limits, resolution and timing of one ultrasonic ranger model."""

    name: str
    min_range_m: float
    max_range_m: float
    resolution_m: float
    ranging_time_s: float
    field_of_view_rad: float = math.radians(60.0)

    def __post_init__(self) -> None:
        if not 0 < self.min_range_m < self.max_range_m:
            raise SonarSimError(
                f"sonar model {self.name!r}: range {self.min_range_m}-{self.max_range_m} m is invalid"
            )
        if self.resolution_m <= 0 or self.ranging_time_s <= 0:
            raise SonarSimError(f"sonar model {self.name!r}: resolution and ranging time must be positive")


SONAR_MODELS: dict[str, SonarModel] = {
    "srf08": SonarModel("srf08", 0.03, 6.0, 0.01, 0.065),
    "srf04": SonarModel("srf04", 0.03, 3.0, 0.01, 0.045),
}


def get_sonar_model(model: str | SonarModel) -> SonarModel:
    """A :class:`SonarModel` by name (``srf08``, ``srf04``)."""
    if isinstance(model, SonarModel):
        return model
    try:
        return SONAR_MODELS[model]
    except KeyError:
        raise SonarSimError(f"unknown sonar model {model!r}; known: {', '.join(SONAR_MODELS)}") from None


def beam_half_apertures_deg(range_m: Any) -> tuple[FloatArray, FloatArray]:
    """(left, right) half-apertures of the beam at ``range_m`` (Appendix A model, constant beyond 1 m)."""
    from mapping.sonar import MODEL_MAX_RANGE_CM, half_apertures_deg

    d_cm = np.clip(np.asarray(range_m, dtype=float) * 100.0, 1e-6, MODEL_MAX_RANGE_CM)
    return half_apertures_deg(d_cm)


def _widest_deg() -> tuple[float, float]:
    from mapping.sonar import WIDE_HALF_APERTURE_DEG, half_apertures_deg

    left, right = half_apertures_deg(np.linspace(1.0, 100.0, 400))
    return max(float(left.max()), WIDE_HALF_APERTURE_DEG[0]), max(
        float(right.max()), WIDE_HALF_APERTURE_DEG[1]
    )


def beam_rays(spacing_deg: float = 1.0) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Unit ray directions of one sonar (its frame: x forward, y left, z up) covering the widest beam.

    Returns:
        ``(directions (N, 3), bearing_deg (N,), elevation_deg (N,))``.
    """
    if not 0.05 <= spacing_deg <= 10.0:
        raise SonarSimError(f"ray spacing {spacing_deg} deg: expected 0.05 .. 10")
    left, right = _widest_deg()
    vert = 0.5 * (left + right)
    # grids through 0 so the axis itself is a ray (a wall square to the sonar reads exactly)
    b = np.concatenate(
        [-np.arange(spacing_deg, right + 1e-9, spacing_deg)[::-1], np.arange(0.0, left + 1e-9, spacing_deg)]
    )
    e = np.concatenate(
        [-np.arange(spacing_deg, vert + 1e-9, spacing_deg)[::-1], np.arange(0.0, vert + 1e-9, spacing_deg)]
    )
    bb, ee = np.meshgrid(b, e)
    h = np.where(bb >= 0, left, right)
    keep = (bb / h) ** 2 + (ee / vert) ** 2 <= 1.0
    bb, ee = bb[keep], ee[keep]
    br, er = np.radians(bb), np.radians(ee)
    d = np.column_stack([np.cos(er) * np.cos(br), np.cos(er) * np.sin(br), np.sin(er)])
    return d, bb, ee


class _Beam:
    """Shared ray casting for one or several sonars."""

    def __init__(self, model: SonarModel, spacing_deg: float, max_incidence_deg: float) -> None:
        if not 0 < max_incidence_deg < 90:
            raise SonarSimError(f"max_incidence_deg={max_incidence_deg}: expected 0 < angle < 90")
        self.model = model
        self.dirs, self.bearing_deg, self.elevation_deg = beam_rays(spacing_deg)
        self._rays: npt.NDArray[np.float32] | None = None  # Embree's (origin, direction) rows, reused
        self.cos_incidence = math.cos(math.radians(max_incidence_deg))
        # the bisection behind the model is exact but slow per ray: tabulate it every 2 mm
        self._table_m = np.linspace(0.002, 1.0, 500)
        self._table_left, self._table_right = beam_half_apertures_deg(self._table_m)
        self._layout: tuple[Any, ...] | None = None  # the rays in the raster's bins (built at first use)
        self._mesh: tuple[Any, ...] = (None, None, None)  # (mirror's tri_vertices, chunks, bounds)

    def _raster_layout(self) -> tuple[Any, ...]:
        """The beam's rays sorted into the raster's (a, c) bins, with bearing and elevation in the same
        order (:mod:`sim._sonar_raster`)."""
        if self._layout is None:
            from sim._sonar_raster import beam_layout

            order, rays, grid, bin_start = beam_layout(self.dirs)
            self._layout = (
                rays,
                grid,
                bin_start,
                np.ascontiguousarray(self.bearing_deg[order]),
                np.ascontiguousarray(self.elevation_deg[order]),
            )
        return self._layout

    def _raster_mesh(self, mirror: MeshMirror) -> tuple[Any, Any]:
        """Chunks and bounding spheres of the mirror's triangles, recomputed when it was rebuilt
        (each rebuild makes new flat arrays, so the vertex array's identity tells)."""
        verts = mirror.tri_vertices
        if self._mesh[0] is not verts:
            from sim._sonar_raster import mesh_chunks

            chunks, bounds = mesh_chunks(verts, mirror.tri_faces, mirror.tri_geometry)
            self._mesh = (verts, chunks, bounds)
        return self._mesh[1], self._mesh[2]

    def apertures(self, r: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Tabulated (left, right) half-apertures at ranges ``r`` (m), constant beyond 1 m."""
        return np.interp(r, self._table_m, self._table_left), np.interp(r, self._table_m, self._table_right)

    def first_echo(
        self, mirror: MeshMirror, poses: list[FloatArray], *, compiled: bool = True, caster: str | None = None
    ) -> FloatArray:
        """Raw first-echo distance (m, unquantised, NaN = none) for each sonar pose.

        Args:
            mirror: the scene (synced here).
            poses: k world poses (4x4) of the sonars, x = the axis.
            compiled: False runs the echo rule in numpy over Embree's hits (the reference the tests
                compare with), whatever ``caster`` says.
            caster: ``"raster"`` (None: :data:`DEFAULT_CASTER`) casts and applies the echo rule in
                one compiled call over the mirror's flat triangle arrays (:mod:`sim._sonar_raster`,
                exact: Embree's answer up to its float32 rounding); ``"embree"`` casts through Open3D
                and applies the rule in one compiled pass over its raw hits.

        Returns:
            (k,) float64 first echoes.

        Raises:
            SonarSimError: an unknown caster. Non-finite poses are refused by :meth:`MeshMirror.cast`.
        """
        caster = DEFAULT_CASTER if caster is None else caster
        if caster not in ("raster", "embree"):
            raise SonarSimError(f"caster={caster!r}: expected 'raster' or 'embree'")
        n = len(self.dirs)
        stack = np.asarray(poses, dtype=float)  # (k, 4, 4)
        mirror.sync()
        finite = math.isfinite(float(stack.sum()))
        if compiled and finite and caster == "raster":
            from sim._sonar_raster import first_echoes

            rays, grid, bin_start, bearing, elevation = self._raster_layout()
            chunks, bounds = self._raster_mesh(mirror)
            return first_echoes(  # type: ignore[no-any-return]
                mirror.tri_vertices,
                mirror.tri_faces,
                chunks,
                bounds,
                stack,
                rays,
                grid,
                bin_start,
                float(self.model.max_range_m),
                self.cos_incidence,
                bearing,
                elevation,
                self._table_m,
                self._table_left,
                self._table_right,
            )
        # every sonar's directions in one product: (k, n, 3) = dirs (n, 3) @ R_k^T
        dirs = np.matmul(self.dirs, stack[:, :3, :3].transpose(0, 2, 1)).reshape(-1, 3)
        if compiled and finite:
            from sim._kinect_kernels import sonar_first_echo
            from sim._sonar_kernels import fill_rays

            rays = self._rays
            if rays is None or len(rays) != len(dirs):
                rays = self._rays = np.empty((len(dirs), 6), dtype=np.float32)
            fill_rays(stack, dirs, rays)  # each sonar's origin, then the directions, as float32
            t_hit, gid, nrm = mirror.cast_raw(rays)
            return sonar_first_echo(  # type: ignore[no-any-return]
                t_hit,
                gid,
                nrm,
                mirror.invalid_id,
                dirs,
                float(self.model.max_range_m),
                self.cos_incidence,
                self.bearing_deg,
                self.elevation_deg,
                self._table_m,
                self._table_left,
                self._table_right,
            )
        origins = np.concatenate([np.broadcast_to(t[:3, 3], (n, 3)) for t in poses])
        hits = mirror.cast(origins, dirs, max_range=self.model.max_range_m)
        r = hits.distance.reshape(len(poses), n)
        # |cos| of the incidence angle: triangles may be wound either way
        facing = (np.abs(np.einsum("ij,ij->i", hits.normal, dirs)) >= self.cos_incidence).reshape(
            len(poses), n
        )
        left, right = self.apertures(np.where(np.isfinite(r), r, 1.0))
        vert = 0.5 * (left + right)
        h = np.where(self.bearing_deg >= 0, left, right)
        inside = (self.bearing_deg / h) ** 2 + (self.elevation_deg / vert) ** 2 <= 1.0
        ok = np.isfinite(r) & facing & inside
        best = np.where(ok, r, np.inf).min(axis=1)
        return np.where(np.isfinite(best), best, np.nan)

    def finish(self, raw: FloatArray, noise_std_m: float, rng: np.random.Generator | None) -> FloatArray:
        """Noise, cm rounding and range limits applied to raw first-echo distances."""
        m = self.model
        r = np.asarray(raw, dtype=float)
        if noise_std_m > 0:
            if rng is None:
                raise SonarSimError("sonar noise is on but no numpy Generator was given")
            r = r + rng.standard_normal(r.shape) * noise_std_m
        if r.size <= 8:  # an array's three readings: plain floats beat a handful of ufunc calls
            res, lo, hi = m.resolution_m, m.min_range_m, m.max_range_m
            out = [math.nan] * r.size
            for k, v in enumerate(r.ravel().tolist()):
                if math.isfinite(v):
                    q = round(v / res) * res  # half to even, like np.round
                    if lo <= q <= hi:
                        out[k] = q
            return np.array(out, dtype=float).reshape(r.shape)
        r = np.round(r / m.resolution_m) * m.resolution_m
        with np.errstate(invalid="ignore"):
            return np.where((r >= m.min_range_m) & (r <= m.max_range_m), r, np.nan)


class SonarSim:
    """One simulated SRF08/SRF04.

    Args:
        client: PyBullet physics client id.
        model: ``"srf08"``, ``"srf04"`` or a :class:`SonarModel`.
        mirror: a shared :class:`MeshMirror` (made here, excluding ``exclude_bodies``, if None).
        noise_std_m: Gaussian range noise before rounding (0 = off).
        rng: Generator (or int seed) for the noise; None means seed 0.
        ray_spacing_deg: angular spacing of the beam's rays.
        max_incidence_deg: largest angle between surface normal and ray that still echoes.
    """

    def __init__(
        self,
        client: int,
        model: str | SonarModel = "srf08",
        *,
        mirror: MeshMirror | None = None,
        exclude_bodies: Any = (),
        noise_std_m: float = 0.0,
        rng: np.random.Generator | int | None = None,
        ray_spacing_deg: float = 1.0,
        max_incidence_deg: float = 40.0,
        name: str = "sonar",
    ) -> None:
        self.model = get_sonar_model(model)
        self.mirror = mirror if mirror is not None else MeshMirror(client, exclude_bodies=exclude_bodies)
        if noise_std_m < 0:
            raise SonarSimError(f"noise_std_m={noise_std_m}: must be >= 0")
        self.noise_std_m = float(noise_std_m)
        self.rng = (
            rng if isinstance(rng, np.random.Generator) else np.random.default_rng(0 if rng is None else rng)
        )
        self._beam = _Beam(self.model, ray_spacing_deg, max_incidence_deg)
        self.name = name

    def measure(self, pose: Any, *, rng: np.random.Generator | None = None) -> float:
        """Range (m, whole cm; NaN = no echo) of the sonar at world ``pose`` (x = its axis)."""
        raw = self._beam.first_echo(self.mirror, [pose_matrix(pose)])
        return float(self._beam.finish(raw, self.noise_std_m, rng or self.rng)[0])

    def read(self, pose: Any, stamp_ns: int = 0, *, rng: np.random.Generator | None = None) -> RangeReading:
        """A :class:`hw.interfaces.RangeReading` at ``pose``."""
        m = self.model
        return RangeReading(
            int(stamp_ns), self.measure(pose, rng=rng), m.min_range_m, m.max_range_m, m.field_of_view_rad
        )


class SonarArraySim:
    """Three simulated sonars at +outer / 0 / -outer deg (sonars 1, 2, 3 from left to right) on a servo.

    ``array_pose`` is the world pose of the servo's base frame (z = servo axis, x = straight ahead at
    servo angle 0); the servo turns the three sonars together by ``servo_angle_deg`` about z.
    ``sonar_offsets_m`` places each sonar in the turned frame (the thesis stacks them on top of each
    other). ``outer_deg`` and ``sonar_offsets_m`` default to the platform's (``[sonar_arrays]`` of
    ``assets/robchair.toml``, :class:`robchair.platform.spec.SonarArrays`).
    """

    def __init__(
        self,
        client: int,
        model: str | SonarModel = "srf08",
        *,
        mirror: MeshMirror | None = None,
        exclude_bodies: Any = (),
        outer_deg: float | None = None,
        sonar_offsets_m: Any = None,
        noise_std_m: float = 0.0,
        rng: np.random.Generator | int | None = None,
        ray_spacing_deg: float = 1.0,
        max_incidence_deg: float = 40.0,
        name: str = "sonar_array",
    ) -> None:
        self.model = get_sonar_model(model)
        self.mirror = mirror if mirror is not None else MeshMirror(client, exclude_bodies=exclude_bodies)
        if outer_deg is None or sonar_offsets_m is None:
            platform = default_spec().sonar_arrays
            outer_deg = platform.outer_sonar_deg if outer_deg is None else outer_deg
            sonar_offsets_m = platform.sonar_offsets_m if sonar_offsets_m is None else sonar_offsets_m
        offs = np.asarray(sonar_offsets_m, dtype=float)
        if offs.shape != (3, 3):
            raise SonarSimError(f"sonar_offsets_m of shape {offs.shape}: expected (3, 3)")
        self.offsets = offs
        self.yaws_deg = (float(outer_deg), 0.0, -float(outer_deg))
        if noise_std_m < 0:
            raise SonarSimError(f"noise_std_m={noise_std_m}: must be >= 0")
        self.noise_std_m = float(noise_std_m)
        self.rng = (
            rng if isinstance(rng, np.random.Generator) else np.random.default_rng(0 if rng is None else rng)
        )
        self._beam = _Beam(self.model, ray_spacing_deg, max_incidence_deg)
        self.name = name
        # each sonar in the turned frame: fixed, so built once
        self._local = [
            frames.se3_planar(off[0], off[1], math.radians(yaw), off[2])
            for off, yaw in zip(self.offsets, self.yaws_deg)
        ]

    def sonar_poses(self, array_pose: Any, servo_angle_deg: float) -> list[FloatArray]:
        """World poses of sonars 1, 2, 3."""
        base = pose_matrix(array_pose)
        # a turn of 0 is the identity (the product gives base, up to the sign of a zero)
        if servo_angle_deg != 0.0:
            base = base @ frames.se3_planar(0.0, 0.0, math.radians(servo_angle_deg))
        return [base @ local for local in self._local]

    def measure(
        self, array_pose: Any, servo_angle_deg: float = 0.0, *, rng: np.random.Generator | None = None
    ) -> tuple[float, float, float]:
        """Ranges (m; NaN = no echo) of sonars 1, 2, 3."""
        return self.finish(
            self._beam.first_echo(self.mirror, self.sonar_poses(array_pose, servo_angle_deg)), rng
        )

    def finish(self, raw: FloatArray, rng: np.random.Generator | None = None) -> tuple[float, float, float]:
        """Ranges (m; NaN = no echo) of sonars 1, 2, 3 from their raw first echoes (m, NaN = none):
        this array's noise (from ``rng``, else its own stream), cm rounding and range limits."""
        r = self._beam.finish(raw, self.noise_std_m, rng or self.rng)
        return (float(r[0]), float(r[1]), float(r[2]))

    def read(
        self,
        array_pose: Any,
        servo_angle_deg: float = 0.0,
        stamp_ns: int = 0,
        *,
        rng: np.random.Generator | None = None,
    ) -> SonarArrayReading:
        """A :class:`hw.interfaces.SonarArrayReading`."""
        return SonarArrayReading(
            int(stamp_ns), self.measure(array_pose, servo_angle_deg, rng=rng), float(servo_angle_deg)
        )


class SonarGroup:
    """Sonar arrays that fire together, cast in one batched call per physics step.

    The arrays of a chair are read one after the other at the same simulated instant; the first
    read casts the beams of every array of the group in one Embree call and keeps the others' raw
    echoes for the rest of that step. Each ray's hit does not depend on the other rays of a call, so
    the readings are the ones separate casts give, bit for bit. A kept echo is used only for the same
    ``stamp`` and the same array pose; anything else (the chair restarted, a servo reset) casts again.

    Args:
        arrays: ``{name: SonarArraySim}`` sharing one mirror and one beam (model, ray spacing,
            incidence limit).

    Raises:
        SonarSimError: the arrays do not share a mirror and a beam.
    """

    def __init__(self, arrays: dict[str, SonarArraySim]) -> None:
        self.arrays = dict(arrays)
        first = next(iter(self.arrays.values()), None)
        for arr in self.arrays.values():
            assert first is not None
            same = (
                arr.mirror is first.mirror
                and arr.model == first.model
                and arr._beam.cos_incidence == first._beam.cos_incidence
                and np.array_equal(arr._beam.dirs, first._beam.dirs)
            )
            if not same:
                raise SonarSimError(f"sonar array {arr.name!r} does not share the group's mirror and beam")
        self._first = first
        self._stamp: Any = None
        self._poses: dict[str, FloatArray] = {}
        self._raw: dict[str, FloatArray] = {}
        self.casts = 0  # batched casts made (one per physics step when every array is read)

    def raw(self, name: str, pose: Any, stamp: Any, poses: Any) -> FloatArray:
        """Raw first echoes (3,) of array ``name`` at world ``pose`` (servo turn included).

        Args:
            name: the array.
            pose: its world pose now (4x4 or (pos, quat_xyzw)).
            stamp: the simulated instant (equal stamps: nothing has moved in between).
            poses: callable giving ``{name: world pose}`` of every array of the group now; called
                when the instant's batch is cast.
        """
        t = pose_matrix(pose)
        kept = self._raw.get(name)
        if kept is not None and stamp == self._stamp and np.array_equal(self._poses[name], t):
            return kept
        assert self._first is not None
        now = {k: pose_matrix(v) for k, v in poses().items() if k in self.arrays}
        now[name] = t
        names = list(now)
        stack = [s for k in names for s in self.arrays[k].sonar_poses(now[k], 0.0)]
        raw = self._first._beam.first_echo(self._first.mirror, stack)
        self._stamp, self._poses = stamp, now
        self._raw = {k: raw[3 * i : 3 * i + 3] for i, k in enumerate(names)}
        self.casts += 1
        return self._raw[name]
