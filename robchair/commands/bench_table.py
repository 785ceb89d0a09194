"""`robchair bench table DIR...`: the README's benchmark table, regenerated from the benches' JSON.

Every ``robchair bench <name> --out DIR`` writes ``DIR/bench_<name>.json`` with the machine's CPU
count and load average before and after the run (:func:`robchair.commands.bench_output.write_results`).
This command reads those files from the folders it is given (a later folder's file of the same bench
wins), turns each into one Markdown table row (benchmark, command, result, measured on what) and
writes the table into the README between the lines :data:`BEGIN` and :data:`END`, replacing what was
there. A bench this module has no summary for gets a row of its top-level figures.

    robchair bench sim --out runs/b --repeats 3 && robchair bench laser --out runs/b --overwrite
    robchair bench table runs/b                 # rewrites README.md's table
    robchair bench table runs/b --readme /tmp/README.md
"""

from __future__ import annotations

import argparse
import json
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

from robchair.platform.errors import RobChairError

ROOT = Path(__file__).resolve().parents[2]
#: The lines between which the table is written (each on a line of its own).
BEGIN = "<!-- bench-table:begin (robchair bench table DIR...; do not edit by hand) -->"
END = "<!-- bench-table:end -->"
HEADER = "| benchmark | command | result | measured |\n|---|---|---|---|"
#: Row order of the known benches (others follow in name order).
ORDER = ("sim", "sim_live", "mapping", "table52", "env", "laser", "zoom", "sweep", "assist")


class BenchTableError(RobChairError):
    """A results folder, a bench JSON file or the README cannot be used."""


def register(subparsers: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    p = subparsers.add_parser("table", help="write the README's benchmark table from bench_*.json files")
    p.add_argument("dirs", nargs="+", type=Path, metavar="DIR", help="folders holding bench_<name>.json")
    p.add_argument(
        "--readme",
        type=Path,
        default=ROOT / "README.md",
        help="the Markdown file to rewrite (default README.md)",
    )
    p.set_defaults(func=_run)


def _f(x: Any, fmt: str = ".2f", none: str = "-") -> str:
    """A number formatted, or ``none`` when it is missing."""
    return none if not isinstance(x, int | float) or isinstance(x, bool) else format(x, fmt)


def _met(ok: Any) -> str:
    return "met" if ok else "missed"


def _sim(r: dict[str, Any]) -> tuple[str, str, str]:
    parts = []
    targets = r.get("targets_ratio_to_replaced_runner", {})
    for row in r.get("rows", []):
        name, m, old = row["config"]["name"], row["median"], row.get("baseline_median")
        txt = f"{name}: RTF {_f(m.get('rtf'))}"
        if old:
            ratio = m["rtf"] / old["rtf"]
            goal = targets.get(name)
            txt += f", {ratio:.2f}x the replaced runner's {_f(old.get('rtf'))}"
            if goal is not None:
                txt += f" (target >= {goal:g}x: {_met(ratio >= goal)})"
        sim_s = max(m.get("sim_time_s", 1.0), 1e-9)
        stages = [("render", m.get("kinect_ms_per_sim_s")), ("sonar", m.get("sonar_ms_per_sim_s")),
                  ("physics", m.get("physics_ms_per_sim_s"))]  # fmt: skip
        stages += [(k[:-5], v) for k, v in sorted(m.items()) if k.startswith("map ") and k.endswith(" ms/s")]
        loop = 1e3 * m.get("loop_wall_s", 0.0) / sim_s
        rest = loop - sum(v for _, v in stages if isinstance(v, int | float))
        if rest >= 0.0:
            stages.append(("rest", rest))
        txt += "; ms per sim s: " + ", ".join(f"{k} {_f(v, '.0f')}" for k, v in stages)
        if rest < 0.0:  # mapping on its own thread: the stages' sum exceeds the loop's wall time
            txt += f" (they overlap on threads: their sum exceeds the loop's {loop:.0f} by {-rest:.0f})"
        cores = row.get("cores_needed")
        if cores:
            txt += (f"; {_f(cores.get('cpu_ms_per_sim_s'), '.0f')} ms of CPU per sim s, so its target needs "
                    f">= {cores.get('cores')} cores")  # fmt: skip
        bound = row.get("ratio_bound")
        if bound:
            txt += f"; the new loop's simulator stages allow at most {_f(bound.get('max_ratio'))}x"
        parts.append(txt)
    what = (
        f"the one loop (`Runtime`, safety on) on `{r.get('scenario')}`, {r.get('map_kind')} map, all layers: "
        f"physics, Kinect v2 at 30 Hz, six sonars at 20 Hz; {_f(r.get('duration_s'), 'g')} sim s per run"
    )
    return (
        what,
        f"`robchair bench sim --repeats {r.get('repeats', 1)}`",
        ". ".join(parts) + f" (median of {r.get('repeats', 1)})",
    )


def _sim_live(r: dict[str, Any]) -> tuple[str, str, str]:
    med, verdicts = r.get("median_cpu_s_per_sim_s", {}), r.get("verdicts", {})
    res = ", ".join(f"{k} {_f(v)}" for k, v in med.items()) + " CPU s per sim s"
    if verdicts:
        res += "; " + ", ".join(f"{k}: {v}" for k, v in verdicts.items())
    return (
        "the live view's cost (CPU time per simulated second: off, on, with a client)",
        (f"`robchair bench sim --live --repeats {r.get('repeats', 1)}`"),
        res,
    )


def _mapping(r: dict[str, Any]) -> tuple[str, str, str]:
    hd = r.get("hd_frame", {})
    res = (
        f"VHV build of the HD frame {_f(hd.get('vhv_fast_median_ms'), '.1f')} ms wall, "
        f"{_f(hd.get('vhv_fast_cpu_median_ms'), '.1f')} ms CPU (target <= {_f(hd.get('target_ms'), 'g')} ms: "
        f"{_met(hd.get('meets_time_target'))}); Open3D {_f(hd.get('ratio_open3d'), '.1f')}x slower "
        f"(target >= {_f(hd.get('target_ratio_open3d'), 'g')}x: {_met(hd.get('meets_open3d_target'))}); "
        + (
            f"OctoMap {_f(hd.get('ratio_octomap'), '.0f')}x"
            if hd.get("ratio_octomap") is not None
            else "OctoMap not measured (--no-octomap)"
        )
    )
    ev = r.get("evidence") or {}
    ins = (ev.get("insert") or {}).get("verdict") or {}
    if "median_ms" in ins:
        res += (
            f"; probabilistic update {_f(ins.get('median_ms'), '.1f')} ms wall, "
            f"{_f(ins.get('cpu_median_ms'), '.1f')} ms CPU (target <= {_f(ins.get('target_ms'), 'g')} ms: "
            f"{_met(ins.get('meets_time_target'))})"
        )
    df = ev.get("depth_frame") or {}
    depth = df.get("probabilistic") or {}
    if "cpu_median_ms" in depth:
        res += (
            f"; a {df.get('points', 0):,}-point depth frame (512x424 in a full run) into the probabilistic "
            f"map {_f(depth.get('cpu_median_ms'), '.1f')} ms CPU"
        )
    return "VHV build and evidence update of a 1920x1080 frame, one core", "`robchair bench mapping`", res


def _env(r: dict[str, Any]) -> tuple[str, str, str]:
    cells = []
    for row in r.get("rows", []):
        txt = f"{row.get('config')} {_f(row.get('median_steps_per_s'), '.1f')}"
        extra = []
        if row.get("ratio_to_physics_only") is not None and row.get("config") != "physics only":
            extra.append(f"{row['ratio_to_physics_only']:.2f} of physics")
        if row.get("speedup_vs_one_env") is not None:
            extra.append(f"{row['speedup_vs_one_env']:.2f}x one env")
        cells.append(txt + (f" ({', '.join(extra)})" if extra else ""))
    st = r.get("standin")
    if st:
        cells.append(f"a stand-in env doing the light env's CPU per step without RobChair: 2 Async workers "
                     f"{_f(st.get('speedup'))}x one, {_f(st.get('speedup_with_info'))}x with the light env's "
                     "info")  # fmt: skip
    return (
        f"Gymnasium envs through the runtime ({_f(r.get('agent_hz'), 'g')} Hz agent): agent steps/s",
        f"`robchair bench env --repeats {r.get('repeats', 1)}`",
        "; ".join(cells),
    )


def _laser(r: dict[str, Any]) -> tuple[str, str, str]:
    return (
        f"one simulated URG-04LX scan in `{r.get('scene')}`, one thread",
        "`robchair bench laser`",
        f"plane cut {_f(r.get('raster_ms'))} ms, Embree mirror {_f(r.get('embree_ms'))} ms, "
        f"PyBullet `rayTestBatch` {_f(r.get('pybullet_ms'))} ms "
        f"({r.get('faster')} {_f(r.get('ratio'), '.1f')}x faster); within 1 cm on "
        f"{_f(100 * r['agreement_1cm'] if 'agreement_1cm' in r else None, '.1f')} % of the beams",
    )


def _table52(r: dict[str, Any]) -> tuple[str, str, str]:
    s = r.get("summary", {})
    return (
        "the thesis's table 5.2 objects seen by a simulated Kinect v2 HD",
        "`robchair bench table52`",
        f"ratio of means (standard voxels / VHV structures) {_f(s.get('ratio_of_means'))} "
        f"(thesis {_f(s.get('thesis_ratio_of_means'))}); VHV fewer for every object: "
        f"{'yes' if s.get('vhv_fewer_than_voxels_for_every_object') else 'no'}",
    )


def _assist(r: dict[str, Any]) -> tuple[str, str, str]:
    target = r.get("target_ms")
    cells = [
        f"{mode} {_f(ms.get('median'), '.3f')} ms median, p99 {_f(ms.get('p99'), '.3f')}"
        + (f" ({_met(r.get('met', {}).get(mode))})" if mode in r.get("met", {}) else "")
        for mode, ms in (r.get("ms") or {}).items()
    ]
    return (
        f"one assistance decision per cycle (CPU ms; target <= {_f(target, 'g')} ms)",
        "`robchair bench assist`",
        "; ".join(cells),
    )


def _map(r: dict[str, Any]) -> tuple[str, str, str]:
    x, v = r.get("x_real_time") or {}, r.get("verdict") or {}
    share = r.get("inserts_share") or {}
    names = {"read_and_build": "build", "read_and_build_cpu": "build in CPU time", "inserts": "inserts alone",
             "whole": "whole command", "whole_no_pictures": "whole command --no-pictures"}  # fmt: skip
    cells = [
        f"{label} {_f(x.get(k), '.1f')}x real time ({v.get(k, '-')})" for k, label in names.items() if k in x
    ]
    return (
        f"`robchair map` on a {_f(r.get('sim_time_s'), '.0f')} s run's bag "
        f"({_f(r.get('bag_mb'), '.0f')} MB); "
        f"target >= {_f(r.get('target_x_real_time'), 'g')}x real time",
        f"`robchair bench map --repeats {r.get('repeats', 1)}`",
        "; ".join(cells)
        + f"; the inserts are {_f(100 * share['of_build'] if 'of_build' in share else None, '.0f')} "
        "% of the build"
        + (
            f"; with its CPU the build needs >= {r['cores_needed_at_target']} cores for the target"
            if r.get("cores_needed_at_target")
            else ""
        ),
    )


MACHINE_KEYS = {"load_average_before", "load_average_after", "cpus", "cpu_model", "time_utc"}


def _generic(name: str) -> Callable[[dict[str, Any]], tuple[str, str, str]]:
    def row(r: dict[str, Any]) -> tuple[str, str, str]:
        figs = [
            f"{k} {_f(v, '.3g') if not isinstance(v, bool) else v}"
            for k, v in r.items()
            if k not in MACHINE_KEYS and isinstance(v, int | float)
        ]
        return f"`{name}`", f"`robchair bench {name}`", ", ".join(figs[:10]) or "(no scalar figures)"

    return row


SUMMARIES: dict[str, Callable[[dict[str, Any]], tuple[str, str, str]]] = {
    "sim": _sim,
    "sim_live": _sim_live,
    "mapping": _mapping,
    "env": _env,
    "laser": _laser,
    "table52": _table52,
    "assist": _assist,
    "map": _map,
}


def machine(r: dict[str, Any]) -> str:
    """The "measured" cell: CPUs (and model), load average before / after, date (UTC)."""
    l0, l1 = r.get("load_average_before") or [None], r.get("load_average_after") or [None]
    model = r.get("cpu_model") or r.get("processor") or "CPUs"
    return (
        f"{r.get('cpus', '?')} x {model}, load {_f(l0[0], '.1f')} before / {_f(l1[0], '.1f')} after "
        f"(1-min average), {str(r.get('time_utc', '?'))[:10]}"
    )


def load_records(dirs: list[Path]) -> dict[str, dict[str, Any]]:
    """``{bench name: record}`` of every ``bench_<name>.json`` in ``dirs`` (a later folder wins).

    Raises:
        BenchTableError: a folder is missing or holds no bench JSON, or a file is not a JSON object.
    """
    out: dict[str, dict[str, Any]] = {}
    for d in dirs:
        if not d.is_dir():
            raise BenchTableError(f"{d}: not a folder")
        files = sorted(d.glob("bench_*.json"))
        if not files:
            raise BenchTableError(
                f"{d}: no bench_<name>.json file (write one with robchair bench <name> --out {d})"
            )
        for f in files:
            try:
                rec = json.loads(f.read_text(encoding="utf-8"))
            except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
                raise BenchTableError(f"{f}: not readable JSON ({exc})") from None
            if not isinstance(rec, dict):
                raise BenchTableError(f"{f}: expected a JSON object, got {type(rec).__name__}")
            out[f.stem.removeprefix("bench_")] = rec
    return out


def _cell(text: str) -> str:
    return " ".join(text.replace("|", "\\|").split())


def table(records: dict[str, dict[str, Any]]) -> str:
    """The Markdown table (header and one row per bench, in :data:`ORDER`)."""
    names = sorted(records, key=lambda n: (ORDER.index(n) if n in ORDER else len(ORDER), n))
    lines = [HEADER]
    for n in names:
        try:
            cells = SUMMARIES.get(n, _generic(n))(records[n])
        except (KeyError, TypeError, ValueError, ZeroDivisionError) as exc:
            raise BenchTableError(f"bench_{n}.json: not the layout of robchair bench {n} ({exc!r})") from None
        lines.append("| " + " | ".join(_cell(c) for c in (*cells, machine(records[n]))) + " |")
    return "\n".join(lines)


def write_table(readme: Path, text: str) -> None:
    """Replace what stands between :data:`BEGIN` and :data:`END` in ``readme`` by ``text`` (atomically).

    Raises:
        BenchTableError: the file cannot be read, or it lacks the two marker lines in that order.
    """
    try:
        old = readme.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise BenchTableError(f"{readme}: cannot be read ({exc})") from None
    lines = old.split("\n")
    try:
        i, j = lines.index(BEGIN), lines.index(END)
    except ValueError:
        raise BenchTableError(f"{readme}: no line {BEGIN!r} followed by a line {END!r}") from None
    if j < i:
        raise BenchTableError(f"{readme}: the end marker comes before the begin marker")
    new = "\n".join([*lines[: i + 1], text, *lines[j:]])
    tmp = readme.with_name(f".{readme.name}.bench-table.tmp")
    tmp.write_text(new, encoding="utf-8")
    os.replace(tmp, readme)


def _run(args: argparse.Namespace) -> int:
    records = load_records(list(args.dirs))
    text = table(records)
    write_table(args.readme, text)
    print(text)
    print(f"wrote the table of {len(records)} bench(es) into {args.readme}")
    return 0
