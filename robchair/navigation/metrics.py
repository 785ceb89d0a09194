"""Standard navigation metrics of one episode and of a set of episodes.

* Success rate, and SPL, Success weighted by (normalised inverse) Path Length (Anderson et al. 2018,
  "On Evaluation of Embodied Navigation Agents", arXiv:1807.06757):
  ``SPL = mean_i S_i * l_i / max(p_i, l_i)`` with ``l_i`` the shortest path length from start to
  the goal's tolerance circle for the chair and ``p_i`` the length of the path the agent drove.
* Collision rate: the fraction of episodes that ended in a collision.
* Safety interventions per episode: agent steps on which the safety layer changed the command.
* Time to goal (successful episodes), s, and the path length ratio ``p_i / l_i`` (successful episodes).
* The BARN Challenge score (Xiao et al. 2022, "Autonomous Ground Navigation in Highly Constrained
  Spaces: Lessons Learned From the Benchmark Autonomous Robot Navigation Challenge at ICRA 2022"):
  ``s_i = S_i * OT_i / clip(AT_i, 4 OT_i, 8 OT_i)`` with ``OT_i`` the optimal time (shortest path
  length over the chair's top speed) and ``AT_i`` the time the agent took; at most 0.25.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np


def spl_term(success: bool, shortest: float, driven: float) -> float:
    """One episode's SPL term ``S * l / max(p, l)`` (0 for a failure or ``l <= 0``)."""
    if not success or shortest <= 0:
        return 0.0
    return float(shortest / max(driven, shortest))


def barn_score(success: bool, shortest: float, max_speed: float, time_s: float) -> float:
    """One episode's BARN score ``S * OT / clip(AT, 4 OT, 8 OT)``, ``OT = shortest / max_speed``."""
    if not success or shortest <= 0 or max_speed <= 0:
        return 0.0
    ot = shortest / max_speed
    return float(ot / float(np.clip(time_s, 4 * ot, 8 * ot)))


def summarize(episodes: list[dict[str, Any]]) -> dict[str, Any]:
    """Aggregate metrics of per-episode results (keys as written by ``evaluate_episode``).

    Returns:
        ``episodes``, ``success_rate``, ``spl``, ``collision_rate``, ``safety_interventions_per_episode``
        (None when the environment reports no safety layer), ``time_to_goal_s`` and
        ``path_length_ratio`` (means over successful episodes, None without one), ``barn_score``.
    """
    n = len(episodes)
    if n == 0:
        return {"episodes": 0}
    ok = [e for e in episodes if e["success"]]
    interventions = [e["safety_interventions"] for e in episodes if e["safety_interventions"] is not None]

    def mean(xs: list[float]) -> float | None:
        return float(np.mean(xs)) if xs else None

    return {
        "episodes": n,
        "success_rate": len(ok) / n,
        "spl": float(np.mean([e["spl"] for e in episodes])),
        "collision_rate": sum(bool(e["collision"]) for e in episodes) / n,
        "safety_interventions_per_episode": mean(interventions),
        "time_to_goal_s": mean([e["time_s"] for e in ok]),
        "path_length_ratio": mean(
            [e["path_length_m"] / e["shortest_path_m"] for e in ok if e["shortest_path_m"] > 0]
        ),
        "barn_score": float(np.mean([e["barn_score"] for e in episodes])),
    }


def format_table(rows: list[tuple[str, dict[str, Any]]]) -> str:
    """A plain-text table: one row per (label, summary)."""
    cols = (
        ("episodes", "episodes", "{:d}"),
        ("success", "success_rate", "{:.1%}"),
        ("SPL", "spl", "{:.3f}"),
        ("collisions", "collision_rate", "{:.1%}"),
        ("interv./ep", "safety_interventions_per_episode", "{:.2f}"),
        ("time to goal s", "time_to_goal_s", "{:.1f}"),
        ("path ratio", "path_length_ratio", "{:.2f}"),
        ("BARN", "barn_score", "{:.3f}"),
    )
    head = ["policy", *(c[0] for c in cols)]
    body = []
    for label, s in rows:
        cells = [label]
        for _, key, fmt in cols:
            v = s.get(key)
            cells.append("n/a" if v is None or (isinstance(v, float) and math.isnan(v)) else fmt.format(v))
        body.append(cells)
    widths = [max(len(r[k]) for r in [head, *body]) for k in range(len(head))]

    def line(r: list[str]) -> str:
        return "  ".join(
            c.rjust(w) if k else c.ljust(w) for k, (c, w) in enumerate(zip(r, widths, strict=True))
        )

    return "\n".join([line(head), line(["-" * w for w in widths]), *(line(r) for r in body)])
