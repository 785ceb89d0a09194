"""Simulated Hokuyo URG-04LX laser range finder: 682 rays in one plane, datasheet accuracy as noise.

The model (SPEC section 3, Hokuyo URG-04LX datasheet and its SCIP 2.0 ``PP`` answer): steps of
360/1024 = 0.3515625 deg (``ARES`` 1024), the measurable steps 44..725 (``AMIN``, ``AMAX``), step 384
straight ahead (``AFRT``). Steps 44..725 are 725 - 44 + 1 = 682 beams, -340 to +341 steps about the
sensor's x axis (-119.53 to +119.88 deg: the datasheet's "240 deg"), so beam 340 looks straight ahead,
exactly what :mod:`hw.hokuyo` reads from the real sensor and the emulator. Ranges 0.02 - 4 m, one scan
per 100 ms (600 rpm), accuracy +-10 mm up to 1 m and +-1 % of the range beyond.

Rays are cast in the sensor's scan plane against the shared :class:`sim.raycast.MeshMirror`'s
triangles: by default by cutting each triangle with the scan plane and testing the beams its cut
covers (``caster="raster"``, :mod:`sim._laser_raster`, the exact answer without a BVH), or through
Open3D's Embree ``RaycastingScene`` (``"embree"``), or, for comparison, with PyBullet's ``rayTestBatch``
against the collision shapes (``"pybullet"``); ``robchair bench laser`` times them. The chair does
not see itself: the mirror leaves its body out (see :class:`sim.backend.SimChair`).

Ranges follow REP-117 like the driver's: nothing within ``range_max`` is ``+inf``; a surface closer
than ``range_min`` is ``-inf``; otherwise the true range plus Gaussian noise of standard deviation
``accuracy(r) / accuracy_sigmas`` (the datasheet's +- bound is taken as the ``accuracy_sigmas``-sigma
envelope, 3 by default: 99.7 % of the readings inside it), rounded to whole millimetres as the sensor
reports. Noise comes from a ``numpy.random.Generator`` that is passed in, so a seed fixes every scan.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from hw.interfaces import Clock, Device, LaserScan
from sim.errors import SimError
from sim.raycast import MeshMirror, pose_matrix

FloatArray = npt.NDArray[np.float64]

CASTERS = ("raster", "embree", "pybullet")
#: The caster of a :class:`LaserSim` made without one (the chair's): the plane cut. Embree gives the
#: same ranges to its float32 rounding (tests/sim/test_laser_raster.py); a test that replays readings
#: recorded with Embree sets this to ``"embree"``.
DEFAULT_CASTER = "raster"


class LaserSimError(SimError, ValueError):
    """A simulated laser was configured or queried with invalid values."""


@dataclass(frozen=True)
class LaserModel:
    """Geometry, range limits, timing and accuracy of a planar scanning laser.

    Attributes:
        name: Model name.
        n_beams: Beams per scan.
        angle_increment: Angle between beams, rad.
        front_beam: Index of the beam that looks along the sensor's x axis (None: the middle one).
        range_min, range_max: Valid range, m.
        scan_time: Time of one scan, s.
        accuracy_near_m: Accuracy bound up to ``accuracy_knee_m``, m.
        accuracy_knee_m: Range where the bound becomes relative, m.
        accuracy_relative: Accuracy bound beyond the knee, fraction of the range.
        resolution_m: Range quantum the sensor reports, m.
    """

    name: str
    n_beams: int
    angle_increment: float
    range_min: float
    range_max: float
    scan_time: float
    accuracy_near_m: float
    accuracy_knee_m: float
    accuracy_relative: float
    resolution_m: float = 0.001
    front_beam: int | None = None

    def __post_init__(self) -> None:
        if self.n_beams < 1 or not self.angle_increment > 0:
            raise LaserSimError(f"laser model {self.name!r}: needs >= 1 beam and a positive increment")
        if self.front_beam is not None and not 0 <= self.front_beam < self.n_beams:
            raise LaserSimError(f"laser model {self.name!r}: front beam {self.front_beam} outside the scan")
        if not 0 < self.range_min < self.range_max:
            raise LaserSimError(
                f"laser model {self.name!r}: range {self.range_min}-{self.range_max} m invalid"
            )

    @property
    def angle_min(self) -> float:
        front = 0.5 * (self.n_beams - 1) if self.front_beam is None else self.front_beam
        return -front * self.angle_increment

    @property
    def angle_max(self) -> float:
        return self.angle_min + (self.n_beams - 1) * self.angle_increment

    @property
    def time_increment(self) -> float:
        """Time between beams, s (the mirror turns a full revolution per scan)."""
        return self.scan_time * self.angle_increment / (2.0 * math.pi)

    def angles(self) -> FloatArray:
        """(n_beams,) beam angles, rad, REP-103 (0 forward, counter-clockwise positive)."""
        return self.angle_min + self.angle_increment * np.arange(self.n_beams, dtype=np.float64)

    def accuracy(self, range_m: Any) -> FloatArray:
        """The datasheet's +- accuracy bound at ``range_m``, m."""
        r = np.asarray(range_m, dtype=np.float64)
        return np.where(r <= self.accuracy_knee_m, self.accuracy_near_m, self.accuracy_relative * r)


URG_04LX = LaserModel(
    name="urg-04lx",
    n_beams=725 - 44 + 1,  # SCIP PP: AMIN 44 .. AMAX 725
    front_beam=384 - 44,  # AFRT 384
    angle_increment=2.0 * math.pi / 1024.0,
    range_min=0.02,
    range_max=4.0,
    scan_time=0.1,
    accuracy_near_m=0.010,
    accuracy_knee_m=1.0,
    accuracy_relative=0.01,
)


class LaserSim(Device):
    """A simulated URG-04LX in a PyBullet world, a :class:`hw.interfaces.LaserScanner`.

    Use :meth:`scan` with an explicit world pose, or :meth:`read` with the ``pose`` and ``clock``
    given here (e.g. ``pose=lambda: chair.robot.link_transform("laser_link")``).

    Args:
        client: PyBullet physics client id.
        model: the laser model (default :data:`URG_04LX`).
        mirror: a shared :class:`MeshMirror` (made here, leaving out ``exclude_bodies``, if None).
        exclude_bodies: bodies the laser does not see (the chair itself).
        caster: ``"raster"`` (the mirror's triangles cut by the scan plane, :mod:`sim._laser_raster`;
            None: :data:`DEFAULT_CASTER`),
            ``"embree"`` (the mirror through Open3D) or ``"pybullet"`` (``rayTestBatch`` on collision
            shapes; sees every body, ``exclude_bodies`` included).
        noise: add the datasheet accuracy as Gaussian noise.
        accuracy_sigmas: the datasheet bound is this many standard deviations.
        rng: Generator (or int seed) for the noise; None means seed 0.
        pose: ``() -> 4x4`` world pose of ``laser_link`` for :meth:`read`.
        clock: stamps of :meth:`read` (default: 0).
        frame_id: the scans' frame.
    """

    name = "laser-sim"

    def __init__(
        self,
        client: int,
        model: LaserModel = URG_04LX,
        *,
        mirror: MeshMirror | None = None,
        exclude_bodies: Any = (),
        caster: str | None = None,
        noise: bool = True,
        accuracy_sigmas: float = 3.0,
        rng: np.random.Generator | int | None = None,
        pose: Callable[[], Any] | None = None,
        clock: Clock | None = None,
        frame_id: str = "laser_link",
    ) -> None:
        caster = DEFAULT_CASTER if caster is None else caster
        if caster not in CASTERS:
            raise LaserSimError(f"caster={caster!r}: expected one of {CASTERS}")
        if not (math.isfinite(accuracy_sigmas) and accuracy_sigmas > 0):
            raise LaserSimError(f"accuracy_sigmas={accuracy_sigmas!r}: expected a positive number")
        self.client = int(client)
        self.model = model
        self.caster = caster
        self.mirror = mirror
        if caster in ("raster", "embree") and self.mirror is None:
            self.mirror = MeshMirror(client, exclude_bodies=exclude_bodies)
        self.noise = bool(noise)
        self.accuracy_sigmas = float(accuracy_sigmas)
        self.rng = (
            rng if isinstance(rng, np.random.Generator) else np.random.default_rng(0 if rng is None else rng)
        )
        self._pose = pose
        self._clock = clock
        self.frame_id = frame_id
        a = model.angles()
        self._dirs = np.stack([np.cos(a), np.sin(a), np.zeros_like(a)], axis=-1)  # sensor frame
        self._rays = np.empty((len(a), 6), dtype=np.float32)  # Embree's (origin, direction) rows, reused
        self._cos, self._sin = np.cos(a), np.sin(a)  # the raster caster's beam directions (sensor frame)
        # the raster caster's chunks of the mirror's triangles: (the vertex array they are of, chunks,
        # bounds), remade when the mirror is rebuilt (sim._sonar_raster.mesh_chunks)
        self._mesh: tuple[Any, Any, Any] = (None, None, None)

    # ---- casting ----------------------------------------------------------------------------

    def true_ranges(self, pose: Any) -> FloatArray:
        """(n_beams,) distance to the first surface along each beam from the world ``pose``, m
        (``inf`` for none within ``range_max``); no noise, no limits below.

        Raises:
            MeshMirrorError: the pose is not finite or not a pose.
        """
        return self._true_ranges(pose)[0]

    def _true_ranges(self, pose: Any) -> tuple[FloatArray, int | None]:
        """:meth:`true_ranges` and, from Embree's hits, how many beams are measurements."""
        rmax = self.model.range_max
        if self.caster == "raster":
            from sim._laser_raster import planar_first_hits_chunked  # numba, imported when first used

            assert self.mirror is not None
            t = pose_matrix(pose)  # refuses a pose that is not finite
            mirror = self.mirror
            mirror.sync()
            verts = mirror.tri_vertices
            if self._mesh[0] is not verts:  # each mirror rebuild makes new flat arrays
                from sim._sonar_raster import mesh_chunks

                self._mesh = (verts, *mesh_chunks(verts, mirror.tri_faces, mirror.tri_geometry))
            m = self.model
            r = planar_first_hits_chunked(
                verts, mirror.tri_faces, self._mesh[1], self._mesh[2], np.ascontiguousarray(t[:3, :3]),
                np.ascontiguousarray(t[:3, 3]), m.angle_min, m.angle_increment, self._cos, self._sin, rmax,
            )  # fmt: skip
            return r, None
        if self.caster == "embree":
            from sim._laser_kernels import fill_rays, hit_ranges  # numba, imported when first used

            assert self.mirror is not None
            # a float64 (4, 4) array is its own pose matrix; the kernel checks that it is finite
            fast = isinstance(pose, np.ndarray) and pose.shape == (4, 4) and pose.dtype == np.float64
            t = pose if fast else pose_matrix(pose)
            dirs = self._dirs @ t[:3, :3].T
            if not fill_rays(t, dirs, self._rays):  # Embree's (origin, direction) rows, reused
                from sim.raycast import MeshMirrorError

                pose_matrix(t)  # a pose that is not finite raises here, as its own error
                raise MeshMirrorError("ray origins and directions must be finite")
            self.mirror.sync()
            t_hit, gid, _ = self.mirror.cast_raw(self._rays, normals=False)  # one beam, no per-ray checks
            return hit_ranges(t_hit, gid, self.mirror.invalid_id, self.model.range_min, rmax)
        import pybullet as p

        t = pose_matrix(pose)
        origin = t[:3, 3]
        dirs = self._dirs @ t[:3, :3].T
        ends = origin + dirs * rmax
        hits = p.rayTestBatch(
            np.broadcast_to(origin, ends.shape).tolist(), ends.tolist(), physicsClientId=self.client
        )
        frac = np.array([h[2] if h[0] >= 0 else np.inf for h in hits], dtype=np.float64)
        return frac * rmax, None

    def ranges(self, pose: Any, *, rng: np.random.Generator | None = None) -> npt.NDArray[np.float32]:
        """(n_beams,) float32 ranges under REP-117 (see the module docstring) from the world ``pose``.

        Noise: one standard normal per measured beam (finite, within the range limits), in beam
        order, from ``rng`` (default the laser's own generator).
        """
        from sim._laser_kernels import count_measured, readings  # numba, imported when first used

        m = self.model
        r, measured = self._true_ranges(pose)
        z = None
        if self.noise:
            gen = rng if rng is not None else self.rng
            if measured is None:
                measured = count_measured(r, m.range_min, m.range_max)
            z = gen.standard_normal((measured,))
        return readings(r, z, m, self.accuracy_sigmas)

    def ranges_reference(
        self, pose: Any, *, rng: np.random.Generator | None = None
    ) -> npt.NDArray[np.float32]:
        """:meth:`ranges` in numpy passes over the beams (the reference the compiled path is tested
        against): the same readings and the same draws, bit for bit."""
        m = self.model
        t = pose_matrix(pose)
        origin = t[:3, 3]
        dirs = self._dirs @ t[:3, :3].T
        if self.caster == "embree":
            assert self.mirror is not None
            if not (np.isfinite(origin).all() and np.isfinite(dirs).all()):
                from sim.raycast import MeshMirrorError

                raise MeshMirrorError("ray origins and directions must be finite")
            self.mirror.sync()
            rays = self._rays
            rays[:, :3] = origin
            rays[:, 3:] = dirs
            t_hit, gid, _ = self.mirror.cast_raw(rays, normals=False)
            r = t_hit.astype(np.float64)
            r[(gid == self.mirror.invalid_id) | ~(r <= m.range_max)] = np.inf
        else:
            r = self.true_ranges(t)
        hit = np.isfinite(r) & (r <= m.range_max)
        near = hit & (r < m.range_min)
        ok = hit & ~near
        out = np.full(r.shape, np.inf)
        meas = r[ok]
        if self.noise:
            gen = rng if rng is not None else self.rng
            meas = meas + gen.standard_normal(meas.shape) * (m.accuracy(meas) / self.accuracy_sigmas)
        out[ok] = np.round(meas / m.resolution_m) * m.resolution_m
        out[near] = -np.inf
        return out.astype(np.float32)

    def scan(self, pose: Any, stamp_ns: int = 0, *, rng: np.random.Generator | None = None) -> LaserScan:
        """A :class:`hw.interfaces.LaserScan` of the laser at world ``pose`` (4x4 or (pos, quat_xyzw))."""
        m = self.model
        return LaserScan(
            stamp_ns=int(stamp_ns),
            angle_min=m.angle_min,
            angle_max=m.angle_max,
            angle_increment=m.angle_increment,
            time_increment=m.time_increment,
            scan_time=m.scan_time,
            range_min=m.range_min,
            range_max=m.range_max,
            ranges=self.ranges(pose, rng=rng),
            frame_id=self.frame_id,
        )

    # ---- the LaserScanner interface ------------------------------------------------------------

    def read(self) -> LaserScan:
        """A scan at the current ``pose()``, stamped by ``clock``.

        Raises:
            DeviceClosedError: before ``open()`` or after ``close()``.
            LaserSimError: no ``pose`` was given.
        """
        self._check_open()
        if self._pose is None:
            raise LaserSimError("LaserSim.read needs pose=... (a function giving laser_link's world pose)")
        stamp = self._clock.now_ns() if self._clock is not None else 0
        return self.scan(self._pose(), stamp)


def mounted_pose(base_pose: Any, spec: Any = None) -> FloatArray:
    """World pose (4x4) of ``laser_link`` for the chair's ``base_link`` at ``base_pose``, from the spec's
    laser mount (``mounts.laser_link`` in ``assets/robchair.toml``)."""
    from robchair.platform.spec import load_spec

    s = spec if spec is not None else load_spec()
    return pose_matrix(base_pose) @ s.laser_mount.transform()
