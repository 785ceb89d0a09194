"""Procedural triangle meshes for the scenes: primitives and the thesis's objects, written as OBJ.

No licensed mesh fits the thesis's objects (Table 5.2: standing person in three poses, bench, plant,
closet, chair, seated person in two poses, a bookcase front), so they are built here from boxes,
cylinders, spheres and capsules with human-scale dimensions. The OBJ files in ``assets/meshes/`` are
the output of :func:`write_all` (``python -m sim.meshgen`` regenerates them byte for byte; a test checks
that the shipped files match). Frames: x forward (the object's front faces +x), y left, z up, the
object standing on z = 0.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt

from robchair.platform.frames import rotation_rpy
from sim.errors import SimError

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]


@dataclass(frozen=True)
class Mesh:
    """A triangle mesh: ``vertices`` (N, 3) float64 metres, ``faces`` (M, 3) int64 vertex indices (CCW)."""

    vertices: FloatArray
    faces: IntArray

    def transformed(self, rotation: FloatArray | None = None, translation: object = (0.0, 0.0, 0.0)) -> Mesh:
        """Rotate (3x3) then translate the vertices."""
        v = self.vertices if rotation is None else self.vertices @ np.asarray(rotation, dtype=float).T
        return Mesh(v + np.asarray(translation, dtype=float), self.faces)

    def bounds(self) -> tuple[FloatArray, FloatArray]:
        """Axis-aligned (min, max) corners."""
        return self.vertices.min(axis=0), self.vertices.max(axis=0)

    def triangle_areas(self) -> FloatArray:
        a, b, c = (self.vertices[self.faces[:, k]] for k in range(3))
        return 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)


def merge(meshes: list[Mesh]) -> Mesh:
    """Concatenate meshes into one (no welding; enough for rendering and ray casting)."""
    verts, faces, offset = [], [], 0
    for m in meshes:
        verts.append(m.vertices)
        faces.append(m.faces + offset)
        offset += len(m.vertices)
    return Mesh(np.concatenate(verts), np.concatenate(faces))


def box(size: tuple[float, float, float], centre: tuple[float, float, float] = (0, 0, 0)) -> Mesh:
    """Axis-aligned box of full extents ``size`` centred at ``centre`` (12 outward-facing triangles)."""
    hx, hy, hz = (s / 2 for s in size)
    v = np.array([[sx * hx, sy * hy, sz * hz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], float)
    # vertex index = 4*ix + 2*iy + iz
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    f = []
    for a, b, c, d in quads:
        f += [(a, b, c), (a, c, d)]
    return Mesh(v + np.asarray(centre, float), np.array(f, dtype=np.int64))


def cylinder(radius: float, length: float, segments: int = 16) -> Mesh:
    """Closed cylinder along z, centred at the origin."""
    t = np.linspace(0.0, 2 * math.pi, segments, endpoint=False)
    ring = np.stack([radius * np.cos(t), radius * np.sin(t)], axis=1)
    bottom = np.column_stack([ring, np.full(segments, -length / 2)])
    top = np.column_stack([ring, np.full(segments, length / 2)])
    v = np.vstack([bottom, top, [[0, 0, -length / 2], [0, 0, length / 2]]])
    cb, ct = 2 * segments, 2 * segments + 1
    f = []
    for i in range(segments):
        j = (i + 1) % segments
        f += [
            (i, j, segments + j),
            (i, segments + j, segments + i),
            (cb, j, i),
            (ct, segments + i, segments + j),
        ]
    return Mesh(v, np.array(f, dtype=np.int64))


def sphere(radius: float, rings: int = 8, segments: int = 12) -> Mesh:
    """UV sphere centred at the origin."""
    verts = [[0.0, 0.0, radius]]
    for r in range(1, rings):
        phi = math.pi * r / rings
        for s in range(segments):
            th = 2 * math.pi * s / segments
            verts.append(
                [
                    radius * math.sin(phi) * math.cos(th),
                    radius * math.sin(phi) * math.sin(th),
                    radius * math.cos(phi),
                ]
            )
    verts.append([0.0, 0.0, -radius])
    south = len(verts) - 1
    f = []
    for s in range(segments):
        f.append((0, 1 + s, 1 + (s + 1) % segments))
    for r in range(rings - 2):
        a0 = 1 + r * segments
        b0 = a0 + segments
        for s in range(segments):
            s2 = (s + 1) % segments
            f += [(a0 + s, b0 + s, b0 + s2), (a0 + s, b0 + s2, a0 + s2)]
    last = 1 + (rings - 2) * segments
    for s in range(segments):
        f.append((last + s, south, last + (s + 1) % segments))
    return Mesh(np.array(verts, float), np.array(f, dtype=np.int64))


def capsule(radius: float, length: float, rings: int = 4, segments: int = 16) -> Mesh:
    """Closed capsule along z centred at the origin: a cylinder of ``length`` between two hemispheres.

    Args:
        radius: Radius of the cylinder and the caps, m.
        length: Length of the cylindrical part, m (total height ``length + 2 radius``).
        rings: Latitude bands per hemispherical cap.
        segments: Vertices around each ring.
    """
    # profile (radius, z) from the south pole to the north pole; the two equators bound the cylinder
    th = np.linspace(0.0, math.pi / 2, rings + 1)
    south = np.column_stack([radius * np.sin(th), -length / 2 - radius * np.cos(th)])
    north = np.column_stack([radius * np.sin(th[::-1]), length / 2 + radius * np.cos(th[::-1])])
    prof = np.concatenate([south, north])
    t = np.linspace(0.0, 2 * math.pi, segments, endpoint=False)
    inner = prof[1:-1]  # rings with a non-zero radius
    ring_v = [np.column_stack([r * np.cos(t), r * np.sin(t), np.full(segments, z)]) for r, z in inner]
    v = np.vstack([[[0.0, 0.0, prof[0, 1]]], *ring_v, [[0.0, 0.0, prof[-1, 1]]]])
    top = len(v) - 1
    f = []
    for s in range(segments):
        f.append((0, 1 + (s + 1) % segments, 1 + s))
    for k in range(len(inner) - 1):
        a0, b0 = 1 + k * segments, 1 + (k + 1) * segments
        for s in range(segments):
            s2 = (s + 1) % segments
            f += [(a0 + s, a0 + s2, b0 + s2), (a0 + s, b0 + s2, b0 + s)]
    last = 1 + (len(inner) - 1) * segments
    for s in range(segments):
        f.append((last + s, last + (s + 1) % segments, top))
    return Mesh(v, np.array(f, dtype=np.int64))


def limb(p0: tuple[float, float, float], p1: tuple[float, float, float], radius: float) -> Mesh:
    """A cylinder of ``radius`` from point ``p0`` to ``p1`` with spheres at both joints."""
    a, b = np.asarray(p0, float), np.asarray(p1, float)
    d = b - a
    length = float(np.linalg.norm(d))
    if length <= 0:
        raise SimError(f"limb from {p0} to {p1} has zero length")
    z = d / length
    # any rotation taking +z onto d
    helper = np.array([1.0, 0, 0]) if abs(z[0]) < 0.9 else np.array([0, 1.0, 0])
    x = np.cross(helper, z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    rot = np.column_stack([x, y, z])
    return merge(
        [
            cylinder(radius, length).transformed(rot, (a + b) / 2),
            sphere(radius, 6, 10).transformed(translation=a),
            sphere(radius, 6, 10).transformed(translation=b),
        ]
    )


# --- the thesis's objects -------------------------------------------------------------------------

_HIP_Z, _SHOULDER_Z, _NECK_Z = 0.92, 1.42, 1.52


def _torso_head(lean: float = 0.0, base_z: float = _HIP_Z) -> list[Mesh]:
    rot = rotation_rpy(0.0, lean, 0.0)
    h = _SHOULDER_Z - _HIP_Z + 0.06
    torso = box((0.24, 0.38, h), (0, 0, h / 2)).transformed(rot, (0, 0, base_z))
    head_c = rot @ np.array([0, 0, _NECK_Z - _HIP_Z + 0.13]) + np.array([0, 0, base_z])
    neck = limb((0, 0, base_z + h - 0.02), tuple(head_c - np.array([0, 0, 0.1])), 0.05)
    return [torso, neck, sphere(0.11).transformed(translation=head_c)]


def person_standing(pose: int) -> Mesh:
    """A standing adult (1.75 m) facing +x. Pose 0: arms down; 1: arms out; 2: walking stride, arm forward."""
    parts = _torso_head()
    sh = _SHOULDER_Z - 0.03
    if pose == 0:
        parts += [
            limb((0, 0.1, 0.07), (0, 0.1, _HIP_Z), 0.07),
            limb((0, -0.1, 0.07), (0, -0.1, _HIP_Z), 0.07),
        ]
        parts += [
            limb((0, 0.24, sh), (0.02, 0.27, 0.85), 0.045),
            limb((0, -0.24, sh), (0.02, -0.27, 0.85), 0.045),
        ]
    elif pose == 1:
        parts += [
            limb((0, 0.14, 0.07), (0, 0.1, _HIP_Z), 0.07),
            limb((0, -0.14, 0.07), (0, -0.1, _HIP_Z), 0.07),
        ]
        parts += [
            limb((0, 0.24, sh), (0.0, 0.85, sh + 0.05), 0.045),
            limb((0, -0.24, sh), (0.0, -0.85, sh + 0.05), 0.045),
        ]
    elif pose == 2:
        parts += [
            limb((0.3, 0.1, 0.07), (0, 0.1, _HIP_Z), 0.07),
            limb((-0.3, -0.1, 0.07), (0, -0.1, _HIP_Z), 0.07),
        ]
        parts += [
            limb((0, 0.24, sh), (0.45, 0.25, 1.1), 0.045),
            limb((0, -0.24, sh), (-0.2, -0.27, 0.9), 0.045),
        ]
    else:
        raise SimError(f"standing person pose must be 0, 1 or 2, got {pose}")
    parts += (
        [box((0.26, 0.1, 0.07), (0.06, y, 0.035)) for y in (0.1, -0.1)]
        if pose != 2
        else [box((0.26, 0.1, 0.07), (0.36, 0.1, 0.035)), box((0.26, 0.1, 0.07), (-0.24, -0.1, 0.035))]
    )
    return merge(parts)


def chair() -> Mesh:
    """A four-legged chair, seat 0.45 m high, backrest to 0.9 m, front towards +x."""
    parts = [box((0.45, 0.45, 0.04), (0, 0, 0.45))]
    parts += [box((0.04, 0.04, 0.43), (sx * 0.2, sy * 0.2, 0.215)) for sx in (-1, 1) for sy in (-1, 1)]
    parts += [box((0.04, 0.45, 0.42), (-0.205, 0, 0.68))]
    return merge(parts)


def person_seated(pose: int) -> Mesh:
    """An adult seated on :func:`chair`, facing +x. Pose 0: hands on lap; 1: leaning back, arm raised."""
    seat_z = 0.47
    parts = [chair()]
    lean = -0.15 if pose == 1 else 0.05
    if pose not in (0, 1):
        raise SimError(f"seated person pose must be 0 or 1, got {pose}")
    parts += [t.transformed(translation=(-0.08, 0, 0)) for t in _torso_head(lean, seat_z)]
    for y in (0.1, -0.1):
        parts += [
            limb((-0.05, y, seat_z + 0.05), (0.38, y, seat_z + 0.05), 0.07),
            limb((0.38, y, seat_z + 0.05), (0.42, y, 0.06), 0.06),
        ]
        parts.append(box((0.26, 0.1, 0.07), (0.48, y, 0.035)))
    sh = seat_z + _SHOULDER_Z - _HIP_Z - 0.03
    parts.append(limb((-0.08, 0.24, sh), (0.15, 0.22, seat_z + 0.25), 0.045))
    if pose == 0:
        parts.append(limb((-0.08, -0.24, sh), (0.15, -0.22, seat_z + 0.25), 0.045))
    else:
        parts.append(limb((-0.1, -0.24, sh), (0.0, -0.3, sh + 0.55), 0.045))
    return merge(parts)


def bench() -> Mesh:
    """A park bench 1.5 m long: slatted seat at 0.45 m, backrest, two leg frames."""
    parts = [box((0.09, 1.5, 0.035), (x, 0, 0.45)) for x in (-0.15, -0.05, 0.05, 0.15)]
    parts += [box((0.035, 1.5, 0.09), (-0.22, 0, z)) for z in (0.6, 0.72, 0.84)]
    for y in (-0.65, 0.65):
        parts += [
            box((0.05, 0.06, 0.43), (0.15, y, 0.215)),
            box((0.05, 0.06, 0.88), (-0.2, y, 0.44)),
            box((0.4, 0.06, 0.05), (-0.02, y, 0.41)),
        ]
    return merge(parts)


def plant() -> Mesh:
    """A potted plant about 1.3 m tall: pot, stem and a cluster of leaf balls."""
    parts = [
        cylinder(0.2, 0.35).transformed(translation=(0, 0, 0.175)),
        limb((0, 0, 0.3), (0, 0, 0.9), 0.025),
    ]
    rng = np.random.default_rng(52)  # fixed: the shipped mesh must be reproducible
    for _ in range(14):
        c = rng.normal((0, 0, 0.95), (0.18, 0.18, 0.2))
        parts.append(sphere(float(rng.uniform(0.1, 0.17)), 6, 10).transformed(translation=c))
    return merge(parts)


def closet() -> Mesh:
    """A wardrobe 1.0 m wide, 0.55 m deep, 1.95 m high, two doors with handles on its front (+x)."""
    parts = [box((0.55, 1.0, 1.85), (0, 0, 0.1 + 0.925)), box((0.5, 0.96, 0.1), (0, 0, 0.05))]
    parts += [box((0.02, 0.48, 1.8), (0.285, y, 1.025)) for y in (-0.245, 0.245)]
    parts += [box((0.03, 0.02, 0.2), (0.31, y, 1.1)) for y in (-0.04, 0.04)]
    return merge(parts)


def bookcase_front() -> Mesh:
    """The front of a bookcase 1.8 m wide and 2.0 m high: frame, five shelves, rows of books."""
    parts = [box((0.3, 0.03, 2.0), (0, y, 1.0)) for y in (-0.9, 0.9)]
    parts += [box((0.3, 0.03 + 1.8, 0.03), (0, 0, z)) for z in (0.05, 0.45, 0.85, 1.25, 1.65, 1.985)]
    parts.append(box((0.02, 1.8, 2.0), (-0.14, 0, 1.0)))
    rng = np.random.default_rng(5)  # fixed: the shipped mesh must be reproducible
    for z0 in (0.065, 0.465, 0.865, 1.265, 1.665):
        y = -0.88
        while True:
            w = float(rng.uniform(0.02, 0.06))
            if y + w > 0.88:
                break
            h = float(rng.uniform(0.2, 0.33))
            d = float(rng.uniform(0.17, 0.25))
            parts.append(box((d, w, h), (0.13 - d / 2, y + w / 2, z0 + h / 2)))
            y += w + float(rng.uniform(0.0, 0.01))
    return merge(parts)


def table() -> Mesh:
    """An office table 1.4 x 0.8 m, top at 0.75 m (the chair, 1.63 m high, must not drive under it)."""
    parts = [box((0.8, 1.4, 0.04), (0, 0, 0.73))]
    parts += [box((0.05, 0.05, 0.71), (sx * 0.35, sy * 0.65, 0.355)) for sx in (-1, 1) for sy in (-1, 1)]
    return merge(parts)


MESHES: dict[str, Callable[[], Mesh]] = {
    "person_standing_0": lambda: person_standing(0),
    "person_standing_1": lambda: person_standing(1),
    "person_standing_2": lambda: person_standing(2),
    "bench": bench,
    "plant": plant,
    "closet": closet,
    "chair": chair,
    "person_seated_0": lambda: person_seated(0),
    "person_seated_1": lambda: person_seated(1),
    "bookcase_front": bookcase_front,
    "table": table,
}


def obj_text(mesh: Mesh, name: str) -> str:
    """Wavefront OBJ text (6 decimals, 1-based faces) of ``mesh``."""
    lines = [
        f"# {name}: generated by sim/meshgen.py (python -m sim.meshgen); metres, z up, front +x",
        f"o {name}",
    ]
    lines += [f"v {x:.6f} {y:.6f} {z:.6f}" for x, y, z in mesh.vertices]
    lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in mesh.faces]
    return "\n".join(lines) + "\n"


def read_obj(path: Path | str) -> Mesh:
    """Read the vertices and (triangulated) faces of an OBJ file; raise SimError on malformed input."""
    path = Path(path)
    verts: list[list[float]] = []
    faces: list[tuple[int, int, int]] = []
    try:
        text = path.read_text()
    except OSError as exc:
        raise SimError(f"{path}: cannot read mesh ({exc})") from exc
    for lineno, line in enumerate(text.splitlines(), 1):
        parts = line.split()
        if not parts:
            continue
        try:
            if parts[0] == "v":
                verts.append([float(p) for p in parts[1:4]])
            elif parts[0] == "f":
                idx = [int(p.split("/")[0]) for p in parts[1:]]
                idx = [i - 1 if i > 0 else len(verts) + i for i in idx]
                faces += [(idx[0], idx[k], idx[k + 1]) for k in range(1, len(idx) - 1)]
        except (ValueError, IndexError) as exc:
            raise SimError(f"{path}:{lineno}: malformed OBJ line {line!r}") from exc
    if not verts or not faces:
        raise SimError(f"{path}: OBJ has no vertices or no faces")
    v = np.asarray(verts, dtype=float)
    f = np.asarray(faces, dtype=np.int64)
    if not np.isfinite(v).all():
        raise SimError(f"{path}: OBJ has non-finite vertices")
    if f.min() < 0 or f.max() >= len(v):
        raise SimError(f"{path}: OBJ face index out of range (1..{len(v)})")
    return Mesh(v, f)


def write_all(out_dir: Path | str) -> list[Path]:
    """Write every mesh of :data:`MESHES` as ``<name>.obj`` into ``out_dir``; return the paths."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = []
    for name, make in MESHES.items():
        p = out / f"{name}.obj"
        p.write_text(obj_text(make(), name))
        paths.append(p)
    return paths


if __name__ == "__main__":  # pragma: no cover - regenerates the shipped assets
    from robchair.platform.paths import ASSETS

    for p in write_all(ASSETS / "meshes"):
        print(p)
