"""Read a run folder (the output of ``robchair sim`` / ``robchair run``) as plain data, from its files only.

The report (:mod:`robchair.report`) and the Rerun recording (:mod:`robchair.viz.rerun_recording`) are
built from these readers after the run, so they depend on the files' formats and nothing else:

==================  =====================================================================================
file                what is read
==================  =====================================================================================
``metrics.json``    the run's metrics (``safety.stops``: a list of ``{"t_s", "reason", ...}``)
``maps.npz``        per map ``<name>_i``, ``<name>_j`` (cell indices), ``<name>_bottom``, ``<name>_top``
                    (kept-axis metres); paths ``path_<name>`` ((N, 3) x, y, yaw in ``map``) and
                    ``path_t`` (int64 ns); optionally ``grid_cell_size`` (m), ``grid_origin``
                    ((2,) world u, v of the lower-left corner of cell (0, 0), m) and ``grid_axis``
``map/summary.json`` ``parameters.cell_size``, ``parameters.grid_extent`` (u_min, u_max, v_min, v_max),
                    ``parameters.axis`` (the grid geometry when ``maps.npz`` does not carry it; ``map/``,
                    else ``map_odometry/``, else another ``map_*/`` folder)
``map/map.yaml``    map_server ``resolution`` and ``origin`` (last fallback for the geometry; axis z)
``bag/``            the rosbag2 folder (MCAP or sqlite3), read with ``rosbags`` (ROS 2 Humble types)
``timeseries.csv``  per-cycle series, schema in :mod:`robchair.report`
``**/*.png``        pictures
==================  =====================================================================================

Times: ``t = 0`` is the bag's first message (the run recorder stamps ``/tf_static`` at the run's start),
the same zero as ``metrics.json``'s ``safety.stops[].t_s``.
"""

from __future__ import annotations

import csv
import json
import math
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from robchair.platform.errors import RobChairError

BAG_DIR = "bag"
STRUCTURE_FIELDS = ("i", "j", "bottom", "top")


class RunFolderError(RobChairError, ValueError):
    """A run folder or one of its files cannot be read (the message names the file)."""


@dataclass(frozen=True)
class GridGeometry:
    """Where the cells of a map lie in the world.

    Attributes:
        cell_size: cell edge, m.
        origin_uv: world grid-plane coordinates (u, v) of the lower-left corner of cell (0, 0), m.
        axis: the kept axis (``"z"``: u, v = x, y).
        source: the file the geometry was read from.
    """

    cell_size: float
    origin_uv: tuple[float, float]
    axis: str = "z"
    source: str = ""

    def boxes(self, s: MapStructures) -> tuple[np.ndarray, np.ndarray]:
        """World ``(mins, maxs)``, each (K, 3) float64 xyz, of one box per structure."""
        from mapping.grid import AXIS_COLUMNS

        cs = self.cell_size
        u = self.origin_uv[0] + s.i.astype(np.float64) * cs
        v = self.origin_uv[1] + s.j.astype(np.float64) * cs
        cols = list(AXIS_COLUMNS[self.axis])  # type: ignore[index]
        lo = np.empty((s.i.size, 3))
        hi = np.empty((s.i.size, 3))
        lo[:, cols] = np.stack([u, v, s.bottom.astype(np.float64)], axis=1)
        hi[:, cols] = np.stack([u + cs, v + cs, s.top.astype(np.float64)], axis=1)
        return lo, hi


@dataclass(frozen=True)
class MapStructures:
    """The VHV structures of one map as arrays: cell indices ``i``, ``j`` (int), ``bottom``, ``top`` (m)."""

    i: np.ndarray
    j: np.ndarray
    bottom: np.ndarray
    top: np.ndarray

    def __len__(self) -> int:
        return int(self.i.size)


@dataclass(frozen=True)
class BagMessage:
    """One deserialized message: topic, ROS type, time since the run start (s) and the message."""

    topic: str
    msgtype: str
    t_s: float
    msg: Any


class RunFolder:
    """Lazy readers over the files of one run folder.

    Args:
        run_dir: the run folder.

    Raises:
        RunFolderError: ``run_dir`` is not a folder.
    """

    def __init__(self, run_dir: Path | str) -> None:
        self.path = Path(run_dir)
        if not self.path.is_dir():
            raise RunFolderError(f"{self.path}: not a run folder (no such directory)")
        self._npz: dict[str, np.ndarray] | None = None

    # ------------------------------------------------------------------ JSON, arrays, CSV
    def _json(self, rel: str) -> Any:
        p = self.path / rel
        if not p.is_file():
            return None
        try:
            return json.loads(p.read_text(encoding="utf-8"))
        except (UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise RunFolderError(f"{p}: not valid JSON ({exc})") from None

    @property
    def metrics(self) -> dict[str, Any]:
        """``metrics.json`` ({} when absent)."""
        m = self._json("metrics.json")
        if m is not None and not isinstance(m, dict):
            raise RunFolderError(f"{self.path / 'metrics.json'}: expected a JSON object")
        return m or {}

    def safety_stops(self) -> list[dict[str, Any]]:
        """``metrics.json`` ``safety.stops``: entries with a finite ``t_s`` (s) and a reason."""
        safety = self.metrics.get("safety")
        stops = safety.get("stops") if isinstance(safety, dict) else None
        out = []
        for s in stops or []:
            if isinstance(s, dict) and isinstance(s.get("t_s"), int | float) and math.isfinite(s["t_s"]):
                out.append({**s, "reason": str(s.get("reason", "stop"))})
        return out

    @property
    def arrays(self) -> dict[str, np.ndarray]:
        """Every array of ``maps.npz`` ({} when absent)."""
        if self._npz is None:
            p = self.path / "maps.npz"
            self._npz = {}
            if p.is_file():
                try:
                    with np.load(p, allow_pickle=False) as z:
                        self._npz = {k: np.asarray(z[k]) for k in z.files}
                except (ValueError, OSError, EOFError) as exc:
                    raise RunFolderError(f"{p}: not a readable .npz ({exc})") from None
        return self._npz

    def maps(self) -> dict[str, MapStructures]:
        """Map name -> structures, for every complete ``<name>_{i,j,bottom,top}`` set in ``maps.npz``."""
        a = self.arrays
        out: dict[str, MapStructures] = {}
        for key in sorted(a):
            if not key.endswith("_i"):
                continue
            name = key[:-2]
            cols = [a.get(f"{name}_{f}") for f in STRUCTURE_FIELDS]
            if any(c is None for c in cols):
                continue
            i, j, bottom, top = (np.asarray(c).reshape(-1) for c in cols)  # type: ignore[union-attr]
            if not (i.size == j.size == bottom.size == top.size):
                raise RunFolderError(
                    f"{self.path / 'maps.npz'}: map {name!r} has arrays of different lengths"
                )
            out[name] = MapStructures(i, j, bottom, top)
        return out

    def paths(self) -> dict[str, np.ndarray]:
        """Path name -> (N, 3) x, y, yaw (``maps.npz`` ``path_<name>``; ``path_t`` is left out)."""
        out = {}
        for key, arr in self.arrays.items():
            if key.startswith("path_") and key != "path_t" and arr.ndim == 2 and arr.shape[1] >= 2:
                out[key[5:]] = np.asarray(arr, dtype=np.float64)
        return out

    def grid(self) -> GridGeometry | None:
        """The map grid's geometry: ``maps.npz`` keys, else ``map/summary.json``, else ``map/map.yaml``."""
        a = self.arrays
        if "grid_cell_size" in a and "grid_origin" in a:
            origin = np.asarray(a["grid_origin"], dtype=np.float64).reshape(-1)
            axis = str(a["grid_axis"]) if "grid_axis" in a else "z"
            return self._checked(float(a["grid_cell_size"]), (origin[0], origin[1]), axis, "maps.npz")
        for d in self._map_dirs():
            rel = f"{d.name}/summary.json"
            summary = self._json(rel)
            params = summary.get("parameters") if isinstance(summary, dict) else None
            if isinstance(params, dict) and "cell_size" in params and "grid_extent" in params:
                ext = params["grid_extent"]
                if not isinstance(ext, list) or len(ext) != 4:
                    raise RunFolderError(f"{self.path / rel}: grid_extent {ext!r}: expected 4 numbers")
                return self._checked(params["cell_size"], (ext[0], ext[2]), params.get("axis", "z"), rel)
        for d in self._map_dirs():
            yaml_path = d / "map.yaml"
            if yaml_path.is_file():
                import yaml

                try:
                    doc = yaml.safe_load(yaml_path.read_text(encoding="utf-8"))
                    res, origin = doc["resolution"], doc["origin"]
                except (yaml.YAMLError, KeyError, TypeError) as exc:
                    raise RunFolderError(f"{yaml_path}: no resolution / origin ({exc})") from None
                if not isinstance(origin, list) or len(origin) < 2:
                    raise RunFolderError(f"{yaml_path}: origin {origin!r}: expected [x, y, yaw]")
                return self._checked(res, origin, "z", f"{d.name}/map.yaml")
        return None

    def _map_dirs(self) -> list[Path]:
        """The map export folders: ``map/``, then ``map_odometry/``, then any other ``map_*/``."""
        dirs = [
            d
            for d in sorted(self.path.glob("map*"))
            if d.is_dir() and (d.name == "map" or d.name.startswith("map_"))
        ]
        rank = {"map": 0, "map_odometry": 1}
        return sorted(dirs, key=lambda d: (rank.get(d.name, 2), d.name))

    def _checked(self, cs: Any, origin: Sequence[Any], axis: Any, source: str) -> GridGeometry:
        try:
            cell, u0, v0 = float(cs), float(origin[0]), float(origin[1])
        except (TypeError, ValueError, IndexError):
            raise RunFolderError(f"{self.path / source}: grid cell size / origin are not numbers") from None
        if not (cell > 0 and math.isfinite(cell) and math.isfinite(u0) and math.isfinite(v0)):
            raise RunFolderError(
                f"{self.path / source}: grid cell size {cs!r} / origin {origin!r} not usable"
            )
        if axis not in ("x", "y", "z"):
            raise RunFolderError(f"{self.path / source}: grid axis {axis!r}: expected x, y or z")
        return GridGeometry(cell, (u0, v0), str(axis), source)

    def timeseries(self) -> dict[str, np.ndarray] | None:
        """``timeseries.csv`` as column -> float64 array (empty cells NaN); None when absent.

        Raises:
            RunFolderError: no ``t_s`` column, or a cell that is not a number.
        """
        p = self.path / "timeseries.csv"
        if not p.is_file():
            return None
        with p.open(newline="", encoding="utf-8") as f:
            rows = list(csv.reader(f))
        if not rows or "t_s" not in [h.strip() for h in rows[0]]:
            raise RunFolderError(f"{p}: expected a header row with a t_s column")
        header = [h.strip() for h in rows[0]]
        data = np.full((len(rows) - 1, len(header)), np.nan)
        for r, row in enumerate(rows[1:]):
            for c, cell in enumerate(row[: len(header)]):
                cell = cell.strip()
                if cell:
                    try:
                        data[r, c] = float(cell)
                    except ValueError:
                        raise RunFolderError(
                            f"{p}: row {r + 2}, column {header[c]}: {cell!r} is not a number"
                        ) from None
        return {h: data[:, c] for c, h in enumerate(header)}

    def pictures(self) -> list[Path]:
        """Every PNG in the run folder (sorted by relative path; the bag folder is skipped)."""
        return sorted(
            p for p in self.path.rglob("*.png") if BAG_DIR not in p.relative_to(self.path).parts[:1]
        )

    # ------------------------------------------------------------------ bag
    @property
    def bag_path(self) -> Path | None:
        """The rosbag2 folder ``bag/`` (with its ``metadata.yaml``), or None."""
        p = self.path / BAG_DIR
        return p if (p / "metadata.yaml").is_file() else None

    def _reader(self) -> Any:
        from rosbags.rosbag2 import Reader

        bag = self.bag_path
        if bag is None:
            raise RunFolderError(f"{self.path}: no bag ({BAG_DIR}/metadata.yaml)")
        try:
            reader = Reader(bag)
            reader.open()
        except (FileNotFoundError, PermissionError):
            raise
        except Exception as exc:  # rosbags, sqlite3 and mcap share no error base
            raise RunFolderError(f"{bag}: cannot open bag ({type(exc).__name__}: {exc})") from None
        return reader

    def bag_topics(self) -> dict[str, str]:
        """Topic -> ROS type of every connection of the bag ({} when there is no bag)."""
        if self.bag_path is None:
            return {}
        reader = self._reader()
        try:
            return {c.topic: c.msgtype for c in reader.connections}
        finally:
            reader.close()

    def messages(self, topics: Sequence[str] | None = None) -> Iterator[BagMessage]:
        """Deserialized bag messages in time order (all topics, or those named); t_s from the bag's start.

        Raises:
            RunFolderError: the bag cannot be opened or a message cannot be decoded.
        """
        from rosbags.typesys import Stores, get_typestore

        store = get_typestore(Stores.ROS2_HUMBLE)
        reader = self._reader()
        try:
            conns = [c for c in reader.connections if topics is None or c.topic in topics]
            t0 = int(reader.start_time)
            try:
                for conn, stamp, raw in reader.messages(connections=conns):
                    msg = store.deserialize_cdr(raw, conn.msgtype)
                    yield BagMessage(conn.topic, conn.msgtype, (int(stamp) - t0) / 1e9, msg)
            except (OSError, MemoryError):
                raise
            except Exception as exc:  # corrupt storage or payload: assorted error types
                raise RunFolderError(
                    f"{self.bag_path}: cannot read messages ({type(exc).__name__}: {exc})"
                ) from None
        finally:
            reader.close()
