"""One self-contained ``report.html`` per run folder: metrics, pictures, the mapped structures in 3D and
plots over time, readable offline (plotly.js is inlined once, pictures are base64 data URIs).

The report is a pure function of the run folder's files (see :mod:`robchair.run_folder` for what is
read from each); sections whose files are missing are left out with a note.

``timeseries.csv`` (optional, written by the drive loop): one header row, then one row per control
cycle, comma-separated, numbers in plain decimal notation, an empty cell = no value in that cycle.

==================  ======  =========================================================================
column              unit    meaning
==================  ======  =========================================================================
``t_s``             s       time since the run's start (the zero of ``metrics.json`` ``safety.stops``);
                            required, increasing
``v_cmd``           m/s     forward speed written to the motors (after the safety layer)
``w_cmd``           rad/s   yaw rate written to the motors (after the safety layer), REP-103 (+ = left)
``left_rpm_cmd``    rpm     left wheel speed command sent to the motor controller
``right_rpm_cmd``   rpm     right wheel speed command
``left_rpm_meas``   rpm     left wheel speed measured by the encoders
``right_rpm_meas``  rpm     right wheel speed measured by the encoders
``mapping_ms``      ms      wall time spent inserting this cycle's sensor frames into the map (empty
                            when the cycle inserted none)
==================  ======  =========================================================================

Every column except ``t_s`` is optional; unknown columns are listed in the report but not plotted.
"""

from __future__ import annotations

import base64
import html
import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from robchair.run_folder import RunFolder

REPORT_NAME = "report.html"
#: VHV boxes drawn in the 3D view at most (an even subsample beyond; every box is in map/vhv_boxes.ply)
MAX_BOXES_3D = 4000
#: structures whose top is at most this high (m) are drawn last when the cap bites (floor returns)
FLOOR_CLUTTER_M = 0.10
#: safety stops drawn as vertical lines at most (all of them are in the table and the marker trace)
MAX_STOP_LINES = 50
TIMESERIES_COLUMNS = (
    "t_s",
    "v_cmd",
    "w_cmd",
    "left_rpm_cmd",
    "right_rpm_cmd",
    "left_rpm_meas",
    "right_rpm_meas",
    "mapping_ms",
)
_PLOT_CONFIG = {"displaylogo": False, "responsive": True}
#: metrics shown first (those the run has), before the pictures; the full table comes last
KEY_METRICS = (
    "status",
    "route.goal_reached",
    "sim_time_s",
    "route.distance_travelled_m",
    "collisions",
    "real_time_factor",
    "safety.enabled",
    "wall_time_s.total",
    "odometry_drift.final_position_error_m",
    "odometry_drift.matched.final_position_error_m",
    "map.iou_odometry_vs_ground_truth_pose",
    "mapping_ms_per_frame_median",
    "controller.watchdog_trips",
    "driver_fault",
)


def build_report(run_dir: Path | str, out: Path | str | None = None, *, name: str | None = None) -> Path:
    """Write the run's ``report.html`` (default ``<run_dir>/report.html``) and return its path.

    Args:
        run_dir: a run folder of ``robchair sim`` / ``robchair run`` (complete: ``metrics.json`` written).
        out: where to write the page instead.
        name: the run's name on the page (default: the folder's name; pass the final name when
            ``run_dir`` is a staging folder).

    Raises:
        RunFolderError: ``run_dir`` is not a folder or one of its files cannot be read.
    """
    import plotly.offline

    run = RunFolder(run_dir)
    metrics = run.metrics
    stops = run.safety_stops()
    sections = [
        _section("Key metrics", _key_metrics(metrics) if metrics else _note("no metrics.json")),
        _section("Pictures", _pictures(run)),
        _section("Mapped structures (3D)", _structures_3d(run)),
        _section("Over time", _time_plots(run, stops)),
        _section("Safety stops", _stops_table(stops, metrics)),
    ]
    if metrics:
        n = len(flatten_metrics(metrics))
        table = f"<details><summary>all {n} metrics</summary>\n{_metrics_table(metrics)}\n</details>"
        sections.append(_section("All metrics", table))
    run_name = name if name is not None else run.path.resolve().name
    title = f"RobChair run {run_name}"
    status = metrics.get("status", "")
    facts = [f"run folder {run_name}"] + [
        f"{k.replace('_', ' ')} {_fmt(metrics[k])}"
        for k in ("scenario", "backend", "scene", "sensor", "seed", "sim_time_s")
        if metrics.get(k) is not None
    ]
    page = _PAGE.format(
        title=html.escape(str(title)),
        heading=html.escape(str(title)) + (f" <small>({html.escape(str(status))})</small>" if status else ""),
        subtitle=html.escape(" · ".join(facts)),
        plotlyjs=plotly.offline.get_plotlyjs(),
        body="\n".join(sections),
    )
    target = Path(out) if out is not None else run.path / REPORT_NAME
    tmp = target.with_name(f".{target.name}.partial")
    tmp.write_text(page, encoding="utf-8")
    tmp.replace(target)  # the page appears whole or not at all
    return target


# ---------------------------------------------------------------------- pieces of the page
def _section(title: str, body: str) -> str:
    slug = "".join(c if c.isalnum() else "-" for c in title.lower()).strip("-")
    return f'<section id="{slug}"><h2>{html.escape(title)}</h2>\n{body}\n</section>'


def _note(text: str) -> str:
    return f'<p class="note">{html.escape(text)}</p>'


def _fmt(v: Any) -> str:
    if isinstance(v, bool) or v is None:
        return json.dumps(v)
    if isinstance(v, float):
        return f"{v:.6g}" if math.isfinite(v) else str(v)
    if isinstance(v, list):
        if len(v) <= 8 and all(not isinstance(x, dict | list) for x in v):
            return "[" + ", ".join(_fmt(x) for x in v) + "]"
        return f"[{len(v)} entries]"
    return str(v)


def flatten_metrics(metrics: dict[str, Any], prefix: str = "") -> list[tuple[str, str]]:
    """``(dotted key, formatted value)`` rows of a nested metrics document, in document order."""
    rows: list[tuple[str, str]] = []
    for k, v in metrics.items():
        key = f"{prefix}{k}"
        if isinstance(v, dict) and v:
            rows.extend(flatten_metrics(v, key + "."))
        else:
            rows.append((key, _fmt(v)))
    return rows


def _metrics_table(metrics: dict[str, Any], keys: tuple[str, ...] | None = None) -> str:
    rows = flatten_metrics(metrics)
    if keys is not None:  # the chosen keys, in the order given
        found = dict(rows)
        rows = [(k, found[k]) for k in keys if k in found]
    body = "\n".join(f"<tr><td>{html.escape(k)}</td><td>{html.escape(v)}</td></tr>" for k, v in rows)
    return f'<table class="metrics"><tr><th>metric</th><th>value</th></tr>\n{body}\n</table>'


def _key_metrics(metrics: dict[str, Any]) -> str:
    stops = metrics.get("safety", {}).get("stops") if isinstance(metrics.get("safety"), dict) else None
    extra = {"safety.stops (count)": str(len(stops))} if isinstance(stops, list) else {}
    table = _metrics_table({**metrics, **extra}, (*KEY_METRICS[:6], *extra, *KEY_METRICS[6:]))
    return table + _note("every metric: All metrics, at the end of the page")


def _pictures(run: RunFolder) -> str:
    pics = run.pictures()
    if not pics:
        return _note("no pictures in the run folder")
    figs = []
    for p in pics:
        rel = p.relative_to(run.path).as_posix()
        data = base64.b64encode(p.read_bytes()).decode("ascii")
        figs.append(
            f'<figure><img alt="{html.escape(rel)}" src="data:image/png;base64,{data}">'
            f"<figcaption>{html.escape(rel)}</figcaption></figure>"
        )
    return '<div class="pictures">' + "\n".join(figs) + "</div>"


def _plot(fig: Any, div_id: str) -> str:
    return str(fig.to_html(full_html=False, include_plotlyjs=False, div_id=div_id, config=_PLOT_CONFIG))


def select_boxes(mins: np.ndarray, maxs: np.ndarray, cap: int) -> tuple[np.ndarray, np.ndarray, str]:
    """At most ``cap`` of the boxes ``(mins, maxs)`` (K, 3): all when they fit; else those reaching above
    :data:`FLOOR_CLUTTER_M` first, evenly subsampled when still too many. Returns the kept boxes and a
    phrase saying how they were chosen ("" when all are kept)."""
    total = mins.shape[0]
    if total <= cap:
        return mins, maxs, ""
    above = maxs[:, 2] > FLOOR_CLUTTER_M
    how = f" (those reaching above {FLOOR_CLUTTER_M:g} m first"
    if np.count_nonzero(above) >= cap:
        mins, maxs = mins[above], maxs[above]
        how += ", evenly subsampled"
    else:
        order = np.concatenate([np.flatnonzero(above), np.flatnonzero(~above)])[:cap]
        order.sort()
        return mins[order], maxs[order], how + ")"
    keep = np.unique(np.linspace(0, mins.shape[0] - 1, cap).round().astype(np.int64))
    return mins[keep], maxs[keep], how + ")"


def _structures_3d(run: RunFolder) -> str:
    import plotly.graph_objects as go

    maps = run.maps()
    name = "odometry" if "odometry" in maps else next(iter(maps), None)
    if name is None:
        return _note("no maps.npz with VHV structures")
    grid = run.grid()
    if grid is None:
        return _note(
            "no grid geometry (map/summary.json, map/map.yaml or maps.npz grid_cell_size/grid_origin)"
        )
    s = maps[name]
    mins, maxs = grid.boxes(s)
    total = mins.shape[0]
    mins, maxs, how = select_boxes(mins, maxs, MAX_BOXES_3D)
    traces: list[Any] = []
    if mins.shape[0]:
        from mapping.export.meshes import box_mesh

        verts, faces = box_mesh(np.stack([mins, maxs], axis=1))
        verts, faces = verts.astype(np.float32), faces.astype(np.int32)
        traces.append(
            go.Mesh3d(
                x=verts[:, 0],
                y=verts[:, 1],
                z=verts[:, 2],
                i=faces[:, 0],
                j=faces[:, 1],
                k=faces[:, 2],
                intensity=verts[:, 2],
                colorscale="Viridis",
                colorbar={"title": {"text": "z (m)"}},
                flatshading=True,
                name=f"{name} map",
                hovertemplate="x %{x:.2f} m<br>y %{y:.2f} m<br>z %{z:.2f} m<extra></extra>",
            )
        )
    for pname, p in run.paths().items():
        traces.append(
            go.Scatter3d(
                x=p[:, 0],
                y=p[:, 1],
                z=np.zeros(len(p)),
                mode="lines",
                name=f"path ({pname})",
                line={"width": 4},
            )
        )
    fig = go.Figure(traces)
    fig.update_layout(
        height=620,
        margin={"l": 0, "r": 0, "t": 30, "b": 0},
        template="plotly_white",
        scene={"aspectmode": "data", "xaxis_title": "x (m)", "yaxis_title": "y (m)", "zaxis_title": "z (m)"},
        legend={"x": 0, "y": 1},
    )
    caption = (
        f"{name} map: {mins.shape[0]} of {total} structures drawn as boxes{how} (cell {grid.cell_size:g} m, "
        f"geometry from {grid.source}), coloured by height; x, y, z in the map frame (REP-103)."
    )
    return _plot(fig, "structures-3d") + _note(caption)


def _odom_series(run: RunFolder) -> dict[str, np.ndarray] | None:
    if "/odom" not in run.bag_topics():
        return None
    t, v, w = [], [], []
    for m in run.messages(["/odom"]):
        t.append(m.t_s)
        v.append(float(m.msg.twist.twist.linear.x))
        w.append(float(m.msg.twist.twist.angular.z))
    return {"t_s": np.asarray(t), "v": np.asarray(v), "w": np.asarray(w)}


def _time_plots(run: RunFolder, stops: list[dict[str, Any]]) -> str:
    import plotly.graph_objects as go
    from plotly.subplots import make_subplots

    odom = _odom_series(run)
    ts = run.timeseries()
    rows: list[tuple[str, list[Any]]] = []
    speed: list[Any] = []
    yaw: list[Any] = []
    if odom is not None and odom["t_s"].size:
        speed.append(go.Scatter(x=odom["t_s"], y=odom["v"], name="v (/odom)", mode="lines"))
        yaw.append(go.Scatter(x=odom["t_s"], y=odom["w"], name="w (/odom)", mode="lines"))
    notes = []
    if ts is not None:
        t = ts["t_s"]
        for col, target, label in (("v_cmd", speed, "v commanded"), ("w_cmd", yaw, "w commanded")):
            if col in ts:
                target.append(go.Scatter(x=t, y=ts[col], name=label, mode="lines", line={"dash": "dot"}))
        for side in ("left", "right"):
            tr = [
                go.Scatter(
                    x=t,
                    y=ts[f"{side}_rpm_{kind}"],
                    name=f"{side} {label}",
                    mode="lines",
                    line={"dash": "dot"} if kind == "cmd" else {},
                )
                for kind, label in (("cmd", "commanded"), ("meas", "measured"))
                if f"{side}_rpm_{kind}" in ts
            ]
            if tr:
                rows.append((f"{side} wheel (rpm)", tr))
        if "mapping_ms" in ts:
            rows.append(("mapping (ms / frame)", _mapping_traces(t, ts["mapping_ms"])))
        extra = [c for c in ts if c not in TIMESERIES_COLUMNS]
        if extra:
            notes.append("timeseries.csv columns not plotted: " + ", ".join(extra))
    else:
        notes.append(
            "no timeseries.csv: commanded and measured wheel speeds and mapping time are not plotted"
        )
    if odom is None:
        notes.append("no /odom in the bag (or no bag): measured speed and yaw rate are not plotted")
    if speed:
        rows.insert(0, ("v (m/s)", speed))
    if yaw:
        rows.insert(1 if speed else 0, ("w (rad/s)", yaw))
    if not rows:
        return "".join(_note(n) for n in notes)
    fig = make_subplots(
        rows=len(rows),
        cols=1,
        shared_xaxes=True,
        vertical_spacing=0.04,
        subplot_titles=[title for title, _ in rows],
    )
    ranges: dict[int, list[float]] = {}
    for r, (_, traces) in enumerate(rows, 1):
        first = [tr for tr in traces if tr.name and tr.name.startswith(FIRST_FRAME_NAME)]
        rest = [float(v) for tr in traces if tr not in first for v in (tr.y if tr.y is not None else ())]
        top = 1.15 * max(rest) if rest else 0.0
        if first and rest and float(first[0].y[0]) > top:  # the compile would flatten every other frame
            first[0].y = (top,)
            first[0].text = (f"{first[0].text[0]} (off scale)",)
            ranges[r] = [0.0, top * 1.08]
    for r, (title, traces) in enumerate(rows, 1):
        for tr in traces:
            fig.add_trace(tr, row=r, col=1)
        fig.update_yaxes(title_text=title, row=r, col=1, **({"range": ranges[r]} if r in ranges else {}))
    if stops:
        st = np.array([s["t_s"] for s in stops], dtype=np.float64)
        text = [f"{s['reason']}: {s.get('detail', '')}" for s in stops]
        fig.add_trace(
            go.Scatter(
                x=st,
                y=np.zeros(st.size),
                mode="markers",
                name="safety stop",
                hovertext=text,
                marker={"symbol": "x", "size": 10, "color": "crimson"},
            ),
            row=1,
            col=1,
        )
        for x in st[:MAX_STOP_LINES]:
            fig.add_vline(x=float(x), line={"color": "crimson", "width": 1, "dash": "dash"}, opacity=0.5)
    fig.update_xaxes(title_text="t (s since the run start)", row=len(rows), col=1)
    fig.update_layout(
        height=230 * len(rows) + 80, template="plotly_white", margin={"t": 40, "b": 40}, hovermode="x unified"
    )
    return _plot(fig, "time-plots") + "".join(_note(n) for n in notes)


FIRST_FRAME_NAME = "first frame"


def _mapping_traces(t: np.ndarray, ms: np.ndarray) -> list[Any]:
    """Mapping time per frame: the first frame (it includes the one-off compile of the mapping kernels)
    as its own marked point, labelled with its time, and every later frame."""
    import plotly.graph_objects as go

    ok = np.flatnonzero(np.isfinite(ms))
    traces = []
    if ok.size:
        k = int(ok[0])
        value = float(ms[k])
        first = go.Scatter(
            x=[float(t[k])],
            y=[value],
            name=f"{FIRST_FRAME_NAME}: {value:.0f} ms (compile)",
            mode="markers+text",
            text=[f"first frame {value:.0f} ms"],
            textposition="middle right",
            hovertext=[f"{value:.1f} ms"],
            marker={"size": 9, "symbol": "triangle-up", "color": "crimson"},
        )
        traces.append(first)
    later = ok[1:]
    traces.append(
        go.Scatter(x=t[later], y=ms[later], name="mapping time", mode="markers", marker={"size": 4})
    )
    return traces


def _stops_table(stops: list[dict[str, Any]], metrics: dict[str, Any]) -> str:
    safety = metrics.get("safety") if isinstance(metrics.get("safety"), dict) else {}
    enabled = safety.get("enabled") if safety else None
    head = _note(f"safety layer enabled: {json.dumps(enabled)}; {len(stops)} stop(s)")
    if not stops:
        return head
    body = "\n".join(
        f"<tr><td>{s['t_s']:.3f}</td><td>{html.escape(s['reason'])}</td>"
        f"<td>{html.escape(str(s.get('detail', '')))}</td></tr>"
        for s in stops
    )
    return (
        head + f'<table class="stops"><tr><th>t (s)</th><th>reason</th><th>detail</th></tr>\n{body}\n</table>'
    )


_PAGE = """<!DOCTYPE html>
<html lang="en">
<head>
<meta charset="utf-8">
<meta name="viewport" content="width=device-width, initial-scale=1">
<title>{title}</title>
<style>
body {{ font-family: system-ui, sans-serif; margin: 1.5em auto; max-width: 1200px; color: #222; }}
h1 small {{ color: #666; font-weight: normal; }}
table {{ border-collapse: collapse; font-size: 0.9em; }}
td, th {{ border: 1px solid #ddd; padding: 2px 8px; text-align: left; vertical-align: top; }}
tr:nth-child(even) {{ background: #f6f6f6; }}
.pictures {{ display: flex; flex-wrap: wrap; gap: 1em; }}
figure {{ margin: 0; max-width: 100%; }}
figure img {{ max-width: 580px; max-height: 580px; border: 1px solid #ddd; }}
.note {{ color: #555; font-size: 0.9em; }}
</style>
<script>{plotlyjs}</script>
</head>
<body>
<h1>{heading}</h1>
<p class="note">{subtitle}</p>
{body}
</body>
</html>
"""
