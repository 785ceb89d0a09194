"""``map_2d.png`` of a simulated run: the run's 2D occupancy against the scene's ground truth, with the
driven paths.

Cells occupied in the map's height band are black, cells of the scene's static surface in the same band
(:func:`sim.truth.scene_occupancy`) are pink beneath them, and the whole ground-truth, odometry and
(when matching ran) matched paths of the run are drawn, with the route's waypoints. Axes in ``map``
(REP-103/105: x forward at the start, y left), metres.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

MAP_2D_NAME = "map_2d.png"
_PATHS = (("ground_truth", "tab:green", "true path"), ("odometry", "tab:blue", "odometry path"),
          ("matched", "tab:purple", "matched path"))  # fmt: skip


def write_map_2d(res: Any, scenario: Any, band: tuple[float, float], path: Path, *, map_name: str) -> Path:
    """Draw ``res.maps[map_name]``'s occupancy in ``band`` (m) with the scene truth and the run's paths.

    Args:
        res: the run's :class:`robchair.runtime.RunResult` (``maps``, ``paths``: (N, >=2) x, y in m).
        scenario: the run's scenario (its scene and route).
        band: (z_min, z_max) of the occupancy, m.
        path: the PNG to write.
        map_name: which of ``res.maps`` to draw (named in the title).

    Returns:
        ``path``.
    """
    import matplotlib.pyplot as plt

    from mapping.derived import occupancy_codes
    from sim.truth import scene_occupancy

    m = res.maps[map_name]
    occ = occupancy_codes(m, band) == 100
    truth = scene_occupancy(scenario.scene, m.spec, band)
    rgb = np.ones((*occ.shape, 3))
    rgb[truth] = (1.0, 0.78, 0.78)
    rgb[occ] = (0.12, 0.12, 0.12)
    x0, x1, y0, y1 = m.spec.extent
    fig, ax = plt.subplots(figsize=(9, 9 * (y1 - y0) / max(x1 - x0, 1e-9) + 1.2), dpi=110)
    ax.imshow(np.transpose(rgb, (1, 0, 2)), origin="lower", extent=(x0, x1, y0, y1), interpolation="nearest")
    for key, colour, label in _PATHS:
        p = np.asarray(res.paths.get(key, ()), dtype=float)
        if p.ndim == 2 and len(p):
            ax.plot(p[:, 0], p[:, 1], color=colour, lw=1.6, label=label)
    wp = np.asarray([scenario.start[:2], *scenario.route.waypoints], dtype=float)
    ax.plot(wp[:, 0], wp[:, 1], "x", color="tab:orange", label="route waypoints")
    ax.set_title(
        f"{scenario.name}: occupancy {band[0]:g}-{band[1]:g} m of the {map_name.replace('_', '-')} map "
        "(black)\nover the scene's ground truth (pink)"
    )
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_aspect("equal")
    ax.legend(loc="upper right", fontsize=8)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return path
