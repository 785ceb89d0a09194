"""A TF buffer read from a bag: the frame tree of ``/tf``, ``/tf_static`` and odometry, looked up in time.

Each edge is ``parent -> child`` with the transform ``T_parent_child`` (REP-103: x forward, metres,
rotations as unit quaternions x y z w), as ``tf2`` stores it. A static edge holds one transform for
all time; a dynamic edge holds a time series, interpolated between samples like ``tf2``'s buffer:
translation linearly, rotation by spherical linear interpolation of the unit quaternions along the
shorter arc (Shoemake, SIGGRAPH 1985; what ``tf2`` and :class:`scipy.spatial.transform.Slerp` do).
A lookup at a stamp outside a dynamic edge's samples is refused when it is farther than a tolerance
from the nearest sample, and takes that sample when within it.

:meth:`TfBuffer.lookup` chains the edges from a source frame up to the common ancestor with the
target frame and back down, so any two frames of one tree connect.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass, field

import numpy as np

from mapping.errors import MappingError


class TfError(MappingError, LookupError):
    """Two frames that the bag's TF tree does not connect, or a frame it does not have."""


class TfOutOfRange(MappingError, LookupError):
    """A stamp farther from a dynamic edge's samples than the tolerance (``gap_ns`` says how far)."""

    def __init__(self, message: str, gap_ns: int) -> None:
        super().__init__(message)
        self.gap_ns = gap_ns


@dataclass
class _Edge:
    parent: str
    stamps: list[int] = field(default_factory=list)
    translations: list[tuple[float, float, float]] = field(default_factory=list)
    quats: list[tuple[float, float, float, float]] = field(default_factory=list)
    static: bool = False
    _t: np.ndarray | None = None
    _xyz: np.ndarray | None = None
    _q: np.ndarray | None = None  # (n, 4) unit quaternions x y z w

    def freeze(self) -> None:
        t = np.asarray(self.stamps, dtype=np.int64)
        order = np.argsort(t, kind="stable")
        t = t[order]
        keep = np.append(t[1:] != t[:-1], True)  # equal stamps: the last one written wins
        idx = order[keep]
        self._t = t[keep]
        self._xyz = np.asarray(self.translations, dtype=np.float64)[idx]
        q = np.asarray(self.quats, dtype=np.float64).reshape(-1, 4)[idx]
        norm = np.linalg.norm(q, axis=1, keepdims=True)
        if not (np.isfinite(q).all() and (norm > 0).all()):
            raise MappingError(
                f"a transform from {self.parent!r}: its rotation is not a finite non-zero quaternion"
            )
        self._q = q / norm

    def at(self, stamp_ns: int, tolerance_ns: int, child: str) -> np.ndarray:
        assert self._t is not None and self._xyz is not None and self._q is not None
        out = np.eye(4)
        if self.static:
            out[:3, :3], out[:3, 3] = _matrix(self._q[-1]), self._xyz[-1]
            return out
        t0, t1 = int(self._t[0]), int(self._t[-1])
        gap = max(t0 - stamp_ns, stamp_ns - t1, 0)
        if gap > tolerance_ns:
            raise TfOutOfRange(
                f"{self.parent} -> {child} is known from {t0 / 1e9:.3f} s to {t1 / 1e9:.3f} s, "
                f"not at {stamp_ns / 1e9:.3f} s",
                gap,
            )
        s = min(max(stamp_ns, t0), t1)
        if self._t.size == 1:
            out[:3, :3], out[:3, 3] = _matrix(self._q[0]), self._xyz[0]
            return out
        i = int(np.clip(np.searchsorted(self._t, s, side="right") - 1, 0, self._t.size - 2))
        a = (s - int(self._t[i])) / float(int(self._t[i + 1]) - int(self._t[i]))
        out[:3, :3] = _matrix(_slerp(self._q[i], self._q[i + 1], a))
        out[:3, 3] = (1.0 - a) * self._xyz[i] + a * self._xyz[i + 1]
        return out


def _slerp(q0: np.ndarray, q1: np.ndarray, a: float) -> np.ndarray:
    """The unit quaternion a fraction ``a`` (0..1) of the way from ``q0`` to ``q1`` along the shorter arc."""
    d = float(q0 @ q1)
    if d < 0.0:  # q and -q are one rotation: take the nearer of the two
        q1, d = -q1, -d
    if d > 1.0 - 1e-12:
        q = q0 + a * (q1 - q0)
        return np.asarray(q / np.linalg.norm(q))
    theta = math.acos(d)
    s = math.sin(theta)
    return np.asarray((math.sin((1.0 - a) * theta) / s) * q0 + (math.sin(a * theta) / s) * q1)


def _matrix(q: np.ndarray) -> np.ndarray:
    """The (3, 3) rotation of a unit quaternion x y z w."""
    x, y, z, w = (float(v) for v in q)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


class TfBuffer:
    """The frame tree of a recording; add every transform, then look frames up at stamps."""

    def __init__(self) -> None:
        self._edges: dict[str, _Edge] = {}
        self._frozen = False

    @staticmethod
    def _name(frame: str) -> str:
        return frame.lstrip("/")  # tf (ROS 1) wrote "/odom"; tf2 writes "odom"

    def add(
        self,
        parent: str,
        child: str,
        stamp_ns: int,
        translation: Iterable[float],
        quat_xyzw: Iterable[float],
        *,
        static: bool = False,
    ) -> None:
        """Add ``T_parent_child`` at ``stamp_ns`` (translation in metres, unit quaternion x y z w).

        A child that later gets another parent keeps the newest parent's samples only (a tree has one
        parent per frame).
        """
        parent, child = self._name(parent), self._name(child)
        edge = self._edges.get(child)
        if edge is None or edge.parent != parent:
            edge = self._edges[child] = _Edge(parent, static=static)
        edge.static = edge.static or static
        edge.stamps.append(int(stamp_ns))
        edge.translations.append(tuple(float(v) for v in translation))  # type: ignore[arg-type]
        edge.quats.append(tuple(float(v) for v in quat_xyzw))  # type: ignore[arg-type]
        self._frozen = False

    def drop(self, child: str) -> None:
        """Forget the edge into ``child`` (before another source of that edge is added)."""
        self._edges.pop(self._name(child), None)
        self._frozen = False

    def __len__(self) -> int:
        return len(self._edges)

    @property
    def frames(self) -> list[str]:
        """Every frame named by an edge, sorted."""
        return sorted(set(self._edges) | {e.parent for e in self._edges.values()})

    def root(self, frame: str) -> str:
        """The top of ``frame``'s tree (``frame`` itself when it has no parent)."""
        frame, seen = self._name(frame), set()
        while frame in self._edges and frame not in seen:
            seen.add(frame)
            frame = self._edges[frame].parent
        return frame

    def _chain(self, frame: str) -> list[str]:
        out = [frame]
        while out[-1] in self._edges and len(out) <= len(self._edges):
            out.append(self._edges[out[-1]].parent)
        return out

    def time_range_ns(self) -> tuple[int, int] | None:
        """First and last stamp of the dynamic edges (None when every edge is static)."""
        stamps = [s for e in self._edges.values() if not e.static for s in e.stamps]
        return (min(stamps), max(stamps)) if stamps else None

    def lookup(self, target: str, source: str, stamp_ns: int, tolerance_ns: int = 0) -> np.ndarray:
        """``T_target_source`` (4, 4) at ``stamp_ns``: maps points in ``source`` into ``target``.

        Raises:
            TfError: The tree does not connect the two frames (the message lists the bag's frames).
            TfOutOfRange: A dynamic edge on the way is farther than ``tolerance_ns`` from the stamp.
        """
        if not self._frozen:
            for e in self._edges.values():
                e.freeze()
            self._frozen = True
        target, source = self._name(target), self._name(source)
        up, down = self._chain(source), self._chain(target)
        common = next((f for f in up if f in down), None)
        if common is None:
            raise TfError(
                f"the TF tree does not connect frame {source!r} to frame {target!r}; "
                f"the bag's frames: {', '.join(self.frames) or 'none'}"
            )
        t_common_source = np.eye(4)
        for f in up[: up.index(common)]:
            t_common_source = self._edges[f].at(stamp_ns, tolerance_ns, f) @ t_common_source
        t_common_target = np.eye(4)
        for f in down[: down.index(common)]:
            t_common_target = self._edges[f].at(stamp_ns, tolerance_ns, f) @ t_common_target
        return np.linalg.solve(t_common_target, t_common_source)
