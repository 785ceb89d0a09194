"""The outputs of `robchair assist-eval`: the table, the paths-per-mode pictures and the report page."""

from __future__ import annotations

from pathlib import Path
from typing import Any

COLUMNS = [("mode", "mode", "{:s}"), ("success", "success_rate", "{:.1%}"), ("coll", "collisions", "{:d}"),
           ("agree", "agreement", "{:.3f}"), ("overr", "overridden_share", "{:.3f}"),
           ("t_goal", "time_to_goal_s", "{:.1f}"), ("stops", "safety_stops", "{:.2f}"),
           ("clear", "min_clearance_m", "{:.3f}"), ("a_lon^", "peak_lon_accel_max", "{:.2f}"),
           ("a_rms", "rms_lon_accel", "{:.3f}"), ("a_lat^", "peak_lat_accel", "{:.2f}"),
           ("jerk^", "peak_jerk", "{:.1f}"), ("stick", "joystick_path", "{:.1f}"),
           ("revs", "reversals", "{:.1f}")]  # fmt: skip


def table_rows(records: list[dict[str, Any]]) -> tuple[list[str], list[list[str]]]:
    """The table's heads and one row of formatted cells per mode record (``-`` for no value)."""
    heads = [h for h, _, _ in COLUMNS]
    rows = [["-" if r[k] is None else f.format(r[k]) for _, k, f in COLUMNS] for r in records]
    return heads, rows


def print_table(records: list[dict[str, Any]]) -> None:
    heads, rows = table_rows(records)
    for cells in [heads, *rows]:
        print(" ".join(f"{c:>8s}" for c in cells))


def picture(sc: dict[str, Any], eps: dict[str, dict[str, Any]], path: Path, user: str) -> None:
    """The floor plan of scenario ``sc`` with each mode's path of its episode ``eps[mode]`` (PNG);
    a mode's legend says how its episode ended (goal, contact or not there)."""
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.4, 4.0), dpi=80)
    for x0, y0, x1, y1 in sc["world"].segments:
        ax.plot([x0, x1], [y0, y1], color="0.3", lw=1.0)
    for mode, ep in eps.items():
        p = ep["path"]
        xy = list(zip(*p, strict=True)) if p else ([], [])
        end = "goal" if ep["success"] else ("contact" if ep["collisions"] else "not there")
        ax.plot(xy[0], xy[1], lw=1.6, label=f"{mode}: {end} {ep['time_s']:.1f} s")
    ax.plot(*sc["start"][:2], "ko", ms=4)
    ax.plot(*sc["route"][-1], "k*", ms=9)
    ax.set_aspect("equal")
    ax.set_title(f"{user} user, floor {sc['seed']}, door {sc['door_width']:.2f} m", fontsize=9)
    ax.legend(fontsize=7, loc="upper right")
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def report_page(doc: dict[str, Any], pictures: list[str], command: str) -> str:
    """``report.md``: what ran, the table per mode and the pictures of the paths per mode."""
    heads, rows = table_rows(doc["modes"])
    lines = [f"# assist-eval: {doc['user']} user on {doc['env']} floors", "",
             f"`{command}`", "",
             f"{doc['episodes']} episodes per mode from evaluation index {doc['seed']}, doorways "
             f"{doc['door_width_m'][0]:.2f}-{doc['door_width_m'][1]:.2f} m; time to goal over the "
             "successful episodes; a_lon^ is the largest peak longitudinal acceleration of any episode "
             "(m/s^2), the other accelerations and jerk are means of per-episode values.", "",
             "| " + " | ".join(heads) + " |", "|" + "---|" * len(heads)]  # fmt: skip
    lines += ["| " + " | ".join(r) + " |" for r in rows]
    lines += ["", "## Paths per mode", ""]
    lines += [f"![{p}]({p})" for p in pictures]
    return "\n".join(lines) + "\n"
