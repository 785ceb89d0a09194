"""Ray casting against a triangle mirror of a PyBullet world (Open3D ``RaycastingScene``, Embree).

PyBullet's own ``rayTestBatch`` is ~20x slower than Embree for a 512x424 depth image and its CPU
renderer ~2x slower, so the simulated Kinect and sonars cast their rays into :class:`MeshMirror`, a
copy of every body's *visual* geometry as triangles (what a camera sees; for meshes the real
triangles, not the convex hulls PyBullet collides with). The mirror keeps one geometry per
(body, link) and follows the bodies: :meth:`MeshMirror.sync` reads every link pose and rebuilds the
Embree scene only when a pose, or the set of bodies, changed (BVH construction for a few thousand
triangles costs well under a millisecond per geometry, cheaper than any incremental scheme Open3D
offers, since ``RaycastingScene`` has no way to move a geometry in place).

Shapes: boxes, spheres, cylinders and capsules are tessellated by :mod:`sim.meshgen`; meshes are
loaded from the visual shape's OBJ file (:func:`sim.meshgen.read_obj`); planes become a 200 m x 200 m
quad. A link whose visual mesh has no file (created from vertex arrays) falls back to the convex hull
of PyBullet's collision mesh vertices; a link that cannot be mirrored at all is counted in
:attr:`MeshMirror.skipped` and logged, never silently dropped.

Frames: PyBullet reports a visual shape's local frame relative to the link frame (URDF frame); for the
base that is the centre-of-mass frame composed with the inverse of the local inertial frame.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from robchair.platform import frames
from sim import meshgen
from sim.errors import SimError
from sim.meshgen import Mesh

log = logging.getLogger(__name__)

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]

#: Half side of the quad that stands in for an infinite PyBullet plane (metres).
PLANE_HALF_SIZE_M = 100.0
#: Value of ``geometry`` for a ray that hit nothing.
NO_HIT = -1

_GEOM_SPHERE, _GEOM_BOX, _GEOM_CYLINDER, _GEOM_MESH, _GEOM_PLANE, _GEOM_CAPSULE = 2, 3, 4, 5, 6, 7
# Tessellation of round shapes: 48 segments keep a chord within 0.22 % of the radius of the true surface.
_SEGMENTS, _SPHERE_RINGS, _CAPSULE_RINGS = 48, 24, 12


class MeshMirrorError(SimError, ValueError):
    """A body could not be mirrored or a ray query was malformed."""


# --------------------------------------------------------------------------------------------
# poses
# --------------------------------------------------------------------------------------------


#: Quaternion (x, y, z, w) of a rotation matrix: :func:`robchair.platform.frames.quat_from_matrix`, under the
#: name this module has always exported.
matrix_to_quat = frames.quat_from_matrix


def pose_matrix(pose: Any) -> FloatArray:
    """A 4x4 homogeneous transform from a 4x4 array or a ``(position, quaternion_xyzw)`` pair.

    Raises:
        MeshMirrorError: the pose has another shape, a zero quaternion or is not finite.
    """
    if isinstance(pose, tuple | list) and len(pose) == 2:
        pos = np.asarray(pose[0], dtype=float).reshape(-1)
        if pos.shape != (3,) or len(pose[1]) != 4:
            raise MeshMirrorError(f"pose {pose!r}: expected (position[3], quaternion_xyzw[4])")
        try:
            t = frames.se3_from_quat(pos, pose[1])
        except ValueError as exc:
            raise MeshMirrorError(f"pose {pose!r}: {exc}") from exc
    else:
        t = np.asarray(pose, dtype=float)
        if t.shape != (4, 4):
            raise MeshMirrorError(f"pose of shape {t.shape}: expected a 4x4 matrix or (position, quaternion)")
    if not np.all(np.isfinite(t)):
        raise MeshMirrorError(f"pose is not finite: {t.tolist()}")
    return t


# --------------------------------------------------------------------------------------------
# tessellation (local frames: centred at the origin, long axis along z, as PyBullet's shapes)
# --------------------------------------------------------------------------------------------


def plane_mesh(
    normal: Any = (0.0, 0.0, 1.0), half_size: float = PLANE_HALF_SIZE_M
) -> tuple[FloatArray, IntArray]:
    """A square quad through the origin, perpendicular to ``normal``."""
    n = np.asarray(normal, dtype=float)
    if np.linalg.norm(n) < 1e-9:
        n = np.array([0.0, 0.0, 1.0])
    n = n / np.linalg.norm(n)
    a = np.cross(n, [1.0, 0.0, 0.0] if abs(n[0]) < 0.9 else [0.0, 1.0, 0.0])
    a /= np.linalg.norm(a)
    b = np.cross(n, a)
    v = half_size * np.array([-a - b, a - b, a + b, -a + b])
    return v, np.array([[0, 1, 2], [0, 2, 3]], dtype=np.int64)


# --------------------------------------------------------------------------------------------
# the mirror
# --------------------------------------------------------------------------------------------


@dataclass
class _Part:
    """One visual shape of a link: triangles in the link frame."""

    vertices: FloatArray
    faces: IntArray


@dataclass
class _LinkGeometry:
    body: int
    link: int
    parts: list[_Part] = field(default_factory=list)
    pose: FloatArray = field(default_factory=lambda: np.full((4, 4), np.nan))
    world_vertices: npt.NDArray[np.float32] | None = None
    faces: IntArray | None = None


@dataclass(frozen=True)
class RayHits:
    """Result of :meth:`MeshMirror.cast`.

    Attributes:
        distance: (N,) ray parameter of the first hit, in units of each direction's length
            (metres for unit directions); ``inf`` where nothing was hit within ``max_range``.
        geometry: (N,) index into :attr:`MeshMirror.keys` of the (body, link) that was hit, or -1.
        normal: (N, 3) float32 unit normal of the hit triangle in the world frame, oriented as the
            triangle is wound (use the absolute value of its dot product with the ray; flipping it
            towards the origin would cost a pass over every ray); NaN where nothing was hit.
    """

    distance: FloatArray
    geometry: npt.NDArray[np.int32]
    normal: FloatArray


class MeshMirror:
    """Triangle copy of a PyBullet world for fast ray casting, following the bodies' poses.

    Args:
        client: PyBullet physics client id.
        exclude_bodies: body unique ids left out entirely (e.g. the robot seen by its own sensors).
        exclude_links: (body, link) pairs left out (link -1 is the base), e.g. the chair's body
            but not its wheels.
        nthreads: threads Embree may use (0 = all cores, 1 = one core).

    Attributes:
        keys: (G, 2) int array of the (body, link) behind each geometry index of :class:`RayHits`.
        skipped: (body, link, reason) of every visual shape that could not be mirrored.
        rebuilds: how many times the Embree scene was rebuilt (diagnostics, benchmarks).
    """

    def __init__(
        self,
        client: int,
        *,
        exclude_bodies: Any = (),
        exclude_links: Any = (),
        nthreads: int = 0,
    ) -> None:
        self.client = int(client)
        self.exclude_bodies = {int(b) for b in exclude_bodies}
        self.exclude_links = {(int(b), int(l)) for b, l in exclude_links}
        if nthreads < 0:
            raise MeshMirrorError(f"nthreads={nthreads}: expected 0 (all cores) or a positive count")
        self.nthreads = int(nthreads)
        self.skipped: list[tuple[int, int, str]] = []
        self.rebuilds = 0
        self._links: list[_LinkGeometry] = []
        self._bodies: tuple[int, ...] = ()
        self._signature: tuple[Any, ...] = ()
        self._scene: Any = None  # Open3D's Embree scene, made on the first Embree query after a build
        self._built = False  # the flat triangle arrays follow the world (see sync)
        self._o3d: Any = None
        self.keys: IntArray = np.zeros((0, 2), dtype=np.int64)
        self._face_normals_world: list[FloatArray] = []
        #: every triangle of the scene as flat arrays (world vertices, faces, geometry index of each
        #: face), refreshed with the Embree scene
        self.tri_vertices: FloatArray = np.zeros((0, 3))
        self.tri_faces: IntArray = np.zeros((0, 3), dtype=np.int64)
        self.tri_geometry: IntArray = np.zeros(0, dtype=np.int64)
        #: optional ``() -> int`` counting the world's physics steps (set by the owner of the world,
        #: e.g. :class:`sim.backend.SimChair`): :meth:`sync` then re-reads the world only once per
        #: step, however many sensors ask (bodies must then only move or appear as the world steps)
        self.step_counter: Any = None
        self._synced_stamp: int | None = None
        #: set by an owner that never removes a body and adds another in its place (e.g.
        #: :class:`sim.backend.SimChair`): :meth:`sync` then compares only the body ids, not every
        #: body's visual shape records, to notice a changed world
        self.bodies_fixed = False
        self._raw_poses: dict[tuple[int, int], tuple[Any, FloatArray]] = {}

    # ---- geometry ---------------------------------------------------------------------------

    def _pb(self) -> Any:
        import pybullet as p

        return p

    def _body_ids(self) -> tuple[int, ...]:
        p = self._pb()
        n = p.getNumBodies(physicsClientId=self.client)
        return tuple(sorted(p.getBodyUniqueId(i, physicsClientId=self.client) for i in range(n)))

    def _part_from_visual(self, rec: tuple[Any, ...]) -> _Part | None:
        body, link, gtype, dims, fname, lpos, lorn = rec[:7]
        if isinstance(fname, bytes):
            fname = fname.decode("utf-8", errors="replace")
        mesh: Mesh | None = None
        if gtype == _GEOM_BOX:
            mesh = meshgen.box((float(dims[0]), float(dims[1]), float(dims[2])))
        elif gtype == _GEOM_SPHERE:
            mesh = meshgen.sphere(float(dims[0]), _SPHERE_RINGS, _SEGMENTS)
        elif gtype == _GEOM_CYLINDER:
            mesh = meshgen.cylinder(float(dims[1]), float(dims[0]), _SEGMENTS)
        elif gtype == _GEOM_CAPSULE:
            mesh = meshgen.capsule(float(dims[1]), float(dims[0]), _CAPSULE_RINGS, _SEGMENTS)
        if mesh is not None:
            v, f = mesh.vertices, mesh.faces
        elif gtype == _GEOM_PLANE:
            normal = self._plane_normal(body, link)
            v, f = plane_mesh(normal)
        elif gtype == _GEOM_MESH:
            if fname and Path(fname).is_file():
                if fname.lower().endswith(".obj"):
                    obj = meshgen.read_obj(fname)
                    v, f = obj.vertices, obj.faces
                else:
                    v, f = self._read_other(fname)
                v = v * np.asarray(dims, dtype=float)
            else:
                hull = self._collision_hull(body, link)
                if hull is None:
                    self.skipped.append((body, link, f"mesh without a readable file ({fname!r})"))
                    log.warning("mirror: body %d link %d: mesh without a readable file %r", body, link, fname)
                    return None
                v, f = hull
        else:
            self.skipped.append((body, link, f"unsupported geometry type {gtype}"))
            log.warning("mirror: body %d link %d: unsupported geometry type %d", body, link, gtype)
            return None
        local = frames.se3_from_quat(lpos, lorn)
        v = v @ local[:3, :3].T + local[:3, 3]
        return _Part(v, f)

    def _read_other(self, fname: str) -> tuple[FloatArray, IntArray]:
        from mapping._deps import import_open3d

        o3d = import_open3d()
        m = o3d.io.read_triangle_mesh(fname)
        v, f = np.asarray(m.vertices, dtype=float), np.asarray(m.triangles, dtype=np.int64)
        if len(f) == 0:
            raise MeshMirrorError(f"mesh file {fname}: no triangles could be read")
        return v, f

    def _plane_normal(self, body: int, link: int) -> tuple[float, float, float]:
        p = self._pb()
        for rec in p.getCollisionShapeData(body, link, physicsClientId=self.client):
            if rec[2] == _GEOM_PLANE and np.linalg.norm(rec[3]) > 0:
                return tuple(float(x) for x in rec[3])  # type: ignore[return-value]
        return (0.0, 0.0, 1.0)

    def _collision_hull(self, body: int, link: int) -> tuple[FloatArray, IntArray] | None:
        p = self._pb()
        try:
            n, verts = p.getMeshData(body, link, physicsClientId=self.client)
        except Exception:  # pybullet raises a bare error for shapes without mesh data
            return None
        if n < 4:
            return None
        from scipy.spatial import ConvexHull

        pts = np.asarray(verts, dtype=float)
        hull = ConvexHull(pts)
        # getMeshData's vertices are in the collision (centre-of-mass) frame; bring them to the
        # link frame so they are treated like every visual part
        if link == -1:
            info = p.getDynamicsInfo(body, -1, physicsClientId=self.client)
            t = frames.se3_from_quat(info[3], info[4])
            pts = pts @ t[:3, :3].T + t[:3, 3]
        return pts, hull.simplices.astype(np.int64)

    def _link_poses(self, body: int, links: list[int]) -> dict[int, FloatArray]:
        """World transform of each link frame (URDF frame) of ``body``."""
        p = self._pb()
        out: dict[int, FloatArray] = {}
        # the raw (position, quaternion) PyBullet reports is compared with the last one first: a
        # body at rest (most of a scene) then costs one query, not a 4x4 composition per sync
        if -1 in links:
            pos, orn = p.getBasePositionAndOrientation(body, physicsClientId=self.client)
            out[-1] = self._pose_from_raw((body, -1), (pos, orn), lambda: self._base_pose(body, pos, orn))
        others = [l for l in links if l >= 0]
        if others:
            states = p.getLinkStates(body, others, computeForwardKinematics=1, physicsClientId=self.client)
            for l, st in zip(others, states):
                pos, orn = st[4], st[5]
                out[l] = self._pose_from_raw(
                    (body, l),
                    (pos, orn),
                    lambda pos=pos, orn=orn: frames.se3_from_quat(pos, orn),
                )
        return out

    def _base_pose(self, body: int, pos: Any, orn: Any) -> FloatArray:
        p = self._pb()
        info = p.getDynamicsInfo(body, -1, physicsClientId=self.client)
        # PyBullet's base pose is the centre-of-mass frame; the link (URDF) frame is offset from it
        return frames.se3_from_quat(pos, orn) @ frames.invert(frames.se3_from_quat(info[3], info[4]))

    def _pose_from_raw(self, key: tuple[int, int], raw: Any, compute: Any) -> FloatArray:
        cached = self._raw_poses.get(key)
        if cached is not None and cached[0] == raw:
            return cached[1]  # type: ignore[no-any-return]
        t = compute()
        self._raw_poses[key] = (raw, t)
        return t  # type: ignore[no-any-return]

    def _collect(self) -> None:
        p = self._pb()
        self._raw_poses = {}
        self._links = []
        self.skipped = []
        for body in self._bodies:
            if body in self.exclude_bodies:
                continue
            per_link: dict[int, _LinkGeometry] = {}
            for rec in p.getVisualShapeData(body, physicsClientId=self.client):
                link = int(rec[1])
                if (body, link) in self.exclude_links:
                    continue
                part = self._part_from_visual(rec)
                if part is None:
                    continue
                per_link.setdefault(link, _LinkGeometry(body, link)).parts.append(part)
            for link in sorted(per_link):
                lg = per_link[link]
                lg.faces = np.concatenate(
                    [
                        pt.faces + off
                        for pt, off in zip(lg.parts, np.cumsum([0] + [len(q.vertices) for q in lg.parts]))
                    ]
                )
                self._links.append(lg)
        self.keys = np.array([[lg.body, lg.link] for lg in self._links], dtype=np.int64).reshape(-1, 2)

    def sync(self) -> bool:
        """Follow the world: re-read poses (and bodies); rebuild the triangles if anything moved (the
        Embree scene then follows on its next query).

        Returns:
            True when the scene was rebuilt.
        """
        stamp = self.step_counter() if self.step_counter is not None else None
        if stamp is not None and stamp == self._synced_stamp and self._built:
            return False  # the world has not stepped since the last sync: nothing can have moved
        p = self._pb()
        bodies = self._body_ids()
        changed = False
        if self.bodies_fixed and self._built and bodies == self._bodies:
            signature = self._signature  # the owner guarantees no body is replaced
        else:
            # PyBullet reuses the unique id of a removed body, so the set of ids alone cannot tell
            # that a body was replaced: compare the visual shape records as well (one call per body)
            signature = tuple(
                (b, tuple(p.getVisualShapeData(b, physicsClientId=self.client))) for b in bodies
            )
        if signature != self._signature:
            self._bodies = bodies
            self._signature = signature
            self._collect()
            changed = True
        by_body: dict[int, list[_LinkGeometry]] = {}
        for lg in self._links:
            by_body.setdefault(lg.body, []).append(lg)
        for body, lgs in by_body.items():
            poses = self._link_poses(body, [lg.link for lg in lgs])
            for lg in lgs:
                t = poses[lg.link]
                # a body at rest gets its cached transform back (the same object): no comparison
                if lg.world_vertices is None or (t is not lg.pose and not np.array_equal(t, lg.pose)):
                    lg.pose = t
                    v = np.concatenate([pt.vertices for pt in lg.parts])
                    lg.world_vertices = np.ascontiguousarray(v @ t[:3, :3].T + t[:3, 3], dtype=np.float32)
                    changed = True
        self._synced_stamp = stamp
        if changed or not self._built:
            self._build()
            return True
        return False

    def _build(self) -> None:
        """Refresh the flat triangle arrays; the Embree scene is made again on its next query.

        Open3D (about a second to import) is loaded only by an Embree query (:meth:`cast`,
        :meth:`cast_raw`): the chair's own casters (the Kinect raster, the sonars' and the laser's)
        work on the flat arrays.
        """
        self._scene = None
        self._built = True
        self.rebuilds += 1
        # the same triangles as flat arrays, for casters that work on them directly (the Kinect's
        # image-space caster, sim._raster_kernels.raster_depth)
        if self._links:
            counts = [len(lg.world_vertices) for lg in self._links]  # type: ignore[arg-type]
            offsets = np.cumsum([0, *counts[:-1]])
            self.tri_vertices = np.concatenate([lg.world_vertices for lg in self._links]).astype(np.float64)  # type: ignore[misc]
            self.tri_faces = np.concatenate(
                [lg.faces + off for lg, off in zip(self._links, offsets)]  # type: ignore[operator]
            ).astype(np.int64)
            self.tri_geometry = np.concatenate(
                [np.full(len(lg.faces), k, dtype=np.int64) for k, lg in enumerate(self._links)]  # type: ignore[arg-type]
            )
        else:
            self.tri_vertices = np.zeros((0, 3))
            self.tri_faces = np.zeros((0, 3), dtype=np.int64)
            self.tri_geometry = np.zeros(0, dtype=np.int64)

    def _embree(self) -> Any:
        """Open3D's ``RaycastingScene`` of the current triangles (made once per build)."""
        if not self._built:
            self.sync()
        if self._scene is not None:
            return self._scene
        if self._o3d is None:
            from mapping._deps import import_open3d

            self._o3d = import_open3d()
        o3d = self._o3d
        scene = o3d.t.geometry.RaycastingScene(nthreads=self.nthreads)
        for k, lg in enumerate(self._links):
            assert lg.world_vertices is not None and lg.faces is not None
            gid = scene.add_triangles(
                o3d.core.Tensor(lg.world_vertices),
                o3d.core.Tensor(np.ascontiguousarray(lg.faces, dtype=np.uint32)),
            )
            if gid != k:  # geometry ids are assigned 0, 1, 2, ... in insertion order
                raise MeshMirrorError(f"Open3D assigned geometry id {gid} to geometry {k}")
        self._scene = scene
        return scene

    @property
    def n_triangles(self) -> int:
        return int(sum(0 if lg.faces is None else len(lg.faces) for lg in self._links))

    # ---- queries ----------------------------------------------------------------------------

    def cast(
        self, origins: Any, directions: Any, max_range: float = math.inf, *, normals: bool = True
    ) -> RayHits:
        """Cast rays; return the first hit of each.

        Args:
            origins: (N, 3) or (3,) world ray origins (broadcast against ``directions``).
            directions: (..., 3) world directions; distances come out in units of their length.
            max_range: hits farther than this (in the same units) count as misses.
            normals: compute the hit normals (skip them to save time when not needed; they are
                then NaN).

        Returns:
            :class:`RayHits` with arrays shaped like ``directions`` without its last axis.

        Raises:
            MeshMirrorError: shapes do not fit or values are not finite.
        """
        d = np.asarray(directions)
        if d.shape[-1:] != (3,):
            raise MeshMirrorError(f"directions of shape {d.shape}: expected (..., 3)")
        shape = d.shape[:-1]
        n_rays = int(np.prod(shape))
        rays = np.empty((n_rays, 6), dtype=np.float32)  # Embree works in float32 anyway
        o = np.asarray(origins, dtype=np.float64)
        if o.shape[-1:] != (3,):
            raise MeshMirrorError(f"origins of shape {o.shape}: expected (3,) or (..., 3)")
        try:
            rays[:, :3] = o.reshape(-1, 3) if o.ndim > 1 else o
        except ValueError:
            raise MeshMirrorError(
                f"origins of shape {o.shape} do not match directions of shape {d.shape}"
            ) from None
        rays[:, 3:] = d.reshape(-1, 3)
        # a non-finite float32 ray has a non-finite component, so the sum is not finite either
        # (one reduction instead of an elementwise isfinite array over every ray)
        if not math.isfinite(float(np.sum(rays, dtype=np.float64))):
            raise MeshMirrorError("ray origins and directions must be finite")
        t, gid, nrm = self.cast_raw(rays, normals=normals)
        miss = (gid == self.invalid_id) | ~(t <= max_range)
        dist = t.astype(np.float64)
        dist[miss] = np.inf
        g = gid.astype(np.int32)
        g[miss] = NO_HIT
        if nrm is not None:
            nrm[miss] = np.nan
        else:
            nrm = np.full((n_rays, 3), np.nan, dtype=np.float32)
        return RayHits(dist.reshape(shape), g.reshape(shape), nrm.reshape((*shape, 3)))

    @property
    def invalid_id(self) -> int:
        """The geometry id :meth:`cast_raw` reports for a ray that hit nothing."""
        return int(self._embree().INVALID_ID)

    def cast_raw(
        self, rays: npt.NDArray[np.float32], *, normals: bool = True
    ) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.uint32], npt.NDArray[np.float32] | None]:
        """Embree's raw answer for an (N, 6) C-contiguous float32 array of (origin, direction) rows.

        No checks and no post-processing (the caller guarantees finite rays): ``(t_hit, geometry_ids,
        primitive_normals)``, misses have ``geometry_ids == invalid_id`` and ``t_hit = inf``; hits
        beyond a range limit are not cut. ``normals=False`` returns None for the normals.
        """
        scene = self._embree()
        res = scene.cast_rays(self._o3d.core.Tensor.from_numpy(rays), nthreads=self.nthreads)
        nrm = res["primitive_normals"].numpy() if normals else None
        return res["t_hit"].numpy(), res["geometry_ids"].numpy(), nrm

    def body_of(self, geometry: Any) -> npt.NDArray[np.int64]:
        """Body unique id for each geometry index (-1 stays -1)."""
        g = np.asarray(geometry, dtype=np.int64)
        out = np.full(g.shape, -1, dtype=np.int64)
        ok = g >= 0
        out[ok] = self.keys[g[ok], 0]
        return out

    def link_of(self, geometry: Any) -> npt.NDArray[np.int64]:
        """Link index for each geometry index (-1 for the base and for misses; see :meth:`body_of`)."""
        g = np.asarray(geometry, dtype=np.int64)
        out = np.full(g.shape, -1, dtype=np.int64)
        ok = g >= 0
        out[ok] = self.keys[g[ok], 1]
        return out
