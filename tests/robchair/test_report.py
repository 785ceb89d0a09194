"""The run report and the run-folder readers it is built from: one self-contained page, the grid
geometry read back exactly, bad files refused with the file named."""

from __future__ import annotations

import base64
import json
import re
from pathlib import Path

import numpy as np
import pytest

from robchair.report import build_report, flatten_metrics, select_boxes
from robchair.run_folder import RunFolder, RunFolderError
from tests.robchair.synthetic_run import write_synthetic_run, write_timeseries


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    r = write_synthetic_run(tmp_path_factory.mktemp("report") / "run", 1.0)
    write_timeseries(r.path, r.cycles)
    return r


def _plot_data(page: str, div_id: str) -> list[dict]:
    """The trace list passed to Plotly.newPlot for ``div_id``."""
    m = re.search(r'Plotly\.newPlot\(\s*"' + re.escape(div_id) + r'",\s*(\[.*?\]),\s*\{', page, re.S)
    assert m, f"no plot {div_id}"
    return json.loads(m.group(1))


def test_report_is_one_self_contained_page_with_metrics_pictures_plots_and_stops(run):
    path = build_report(run.path)
    assert path == run.path / "report.html"
    page = path.read_text(encoding="utf-8")
    # offline: no script, stylesheet or image is fetched from anywhere
    assert not re.search(r'<(script|img|link)[^>]+(src|href)="(https?:)?//', page)
    assert page.count("<script>") >= 1 and page.count("plotly.js v") == 1  # plotly.js inlined once
    # metrics table: flattened keys, lists summarised
    assert "<td>safety.stop_counts.obstacle</td><td>1</td>" in page
    assert "<td>route.goal_reached</td><td>false</td>" in page
    assert "<td>safety.stops</td><td>[2 entries]</td>" in page
    # every picture embedded, bytes identical
    pngs = sorted(p.relative_to(run.path).as_posix() for p in run.path.rglob("*.png"))
    assert pngs == ["scene.png"]
    data = re.findall(r'<img alt="[^"]*" src="data:image/png;base64,([^"]+)"', page)
    assert [base64.b64decode(d) for d in data] == [(run.path / p).read_bytes() for p in pngs]
    # 3D view: one box (8 vertices, 12 triangles) per structure, plus the two paths
    traces = _plot_data(page, "structures-3d")
    mesh = next(t for t in traces if t["type"] == "mesh3d")
    assert len(np.frombuffer(base64.b64decode(mesh["x"]["bdata"]), np.float32)) == 8 * run.n_structures
    assert len(np.frombuffer(base64.b64decode(mesh["i"]["bdata"]), np.int32)) == 12 * run.n_structures
    assert sorted(t["name"] for t in traces if t["type"] == "scatter3d") == [
        "path (ground_truth)",
        "path (odometry)",
    ]
    # plots over time: /odom speed and yaw rate, commands, both wheels, mapping time, the stops
    names = [t.get("name") for t in _plot_data(page, "time-plots")]
    for name in ("v (/odom)", "w (/odom)", "v commanded", "w commanded", "left commanded", "left measured",
                 "right commanded", "right measured", "mapping time", "safety stop"):  # fmt: skip
        assert name in names
    stop_trace = next(t for t in _plot_data(page, "time-plots") if t.get("name") == "safety stop")
    assert stop_trace["hovertext"] == ["obstacle: sonar 0.42 m ahead", "stale_sensor: kinect 0.30 s old"]
    assert "<td>0.300</td><td>obstacle</td><td>sonar 0.42 m ahead</td>" in page


def test_report_without_bag_maps_or_timeseries_says_what_is_missing(tmp_path):
    (tmp_path / "metrics.json").write_text('{"status": "ok", "cycles": 3}')
    page = build_report(tmp_path).read_text(encoding="utf-8")
    assert "<td>cycles</td><td>3</td>" in page
    assert "no maps.npz with VHV structures" in page
    assert "no pictures in the run folder" in page
    assert "no /odom in the bag (or no bag)" in page


def test_box_geometry_from_the_exported_map_matches_the_mapping_core(tmp_path):
    from mapping.derived import vhv_boxes
    from mapping.export import write_map_outputs
    from mapping.grid import GridSpec
    from mapping.vhv import VHVMap

    rng = np.random.default_rng(3)
    m = VHVMap(GridSpec(cell_size=0.1, size_x=4.0, size_y=2.0, centre=(1.3, -0.7)), tolerance=0.05)
    m.insert(rng.uniform((-0.6, -1.6, 0.0), (3.2, 0.2, 1.5), (500, 3)))
    s = m.structures()
    arrays = dict(odometry_i=s.i, odometry_j=s.j, odometry_bottom=s.bottom, odometry_top=s.top)
    np.savez(tmp_path / "maps.npz", **arrays)
    (tmp_path / "map").mkdir()
    write_map_outputs(m, tmp_path / "map")
    expected = np.asarray(vhv_boxes(m))
    folder = RunFolder(tmp_path)
    for source in ("map/summary.json", "map/map.yaml"):
        grid = folder.grid()
        assert grid is not None and grid.source == source
        mins, maxs = grid.boxes(folder.maps()["odometry"])
        np.testing.assert_allclose(mins, expected[:, 0], atol=1e-9)
        np.testing.assert_allclose(maxs, expected[:, 1], atol=1e-6)
        (tmp_path / source).unlink()
    # maps.npz may carry the geometry itself; it wins
    np.savez(tmp_path / "maps.npz", grid_cell_size=0.1, grid_origin=np.array([-0.7, -1.7]), **arrays)
    folder = RunFolder(tmp_path)
    grid = folder.grid()
    assert grid is not None and grid.source == "maps.npz"
    np.testing.assert_allclose(grid.boxes(folder.maps()["odometry"])[0], expected[:, 0], atol=1e-9)


def test_box_cap_keeps_structures_above_the_floor_first():
    mins = np.zeros((10, 3))
    maxs = np.ones((10, 3))
    maxs[::2, 2] = 0.05  # five floor returns
    m, x, how = select_boxes(mins, maxs, 7)
    assert len(m) == 7 and np.count_nonzero(x[:, 2] > 0.1) == 5 and "above 0.1 m first" in how
    m, x, how = select_boxes(mins, maxs, 3)
    assert len(m) == 3 and np.all(x[:, 2] > 0.1) and "evenly subsampled" in how
    assert select_boxes(mins, maxs, 10)[2] == ""


def test_metrics_are_flattened_with_dotted_keys_in_document_order():
    rows = flatten_metrics({"a": 1.23456789, "b": {"c": None, "d": {"e": True}}, "f": [1, 2], "g": {}})
    assert rows == [("a", "1.23457"), ("b.c", "null"), ("b.d.e", "true"), ("f", "[1, 2]"), ("g", "{}")]


@pytest.mark.parametrize(
    ("rel", "content", "message"),
    [
        ("metrics.json", "{not json", "metrics.json: not valid JSON"),
        ("timeseries.csv", "v_cmd\n0.1\n", "timeseries.csv: expected a header row with a t_s column"),
        ("timeseries.csv", "t_s,v_cmd\n0.1,fast\n", "timeseries.csv: row 2, column v_cmd: 'fast' is not"),
        ("maps.npz", "not a zip", "maps.npz: not a readable .npz"),
        ("map/summary.json", '{"parameters": {"cell_size": -1, "grid_extent": [0, 1, 0, 1]}}', "not usable"),
    ],
)
def test_unreadable_run_files_are_refused_naming_the_file(tmp_path, rel, content, message):
    (tmp_path / rel).parent.mkdir(exist_ok=True)
    (tmp_path / rel).write_text(content)
    if not (tmp_path / "maps.npz").exists():
        one = np.zeros(1)
        np.savez(tmp_path / "maps.npz", a_i=one, a_j=one, a_bottom=one, a_top=one + 1)
    with pytest.raises(RunFolderError, match=re.escape(message)):
        build_report(tmp_path)


def test_report_of_a_missing_folder_is_refused(tmp_path):
    with pytest.raises(RunFolderError, match="nope: not a run folder"):
        build_report(tmp_path / "nope")


def test_bag_times_start_at_the_run_start(run):
    first = next(RunFolder(run.path).messages(["/odom"]))
    assert first.t_s == pytest.approx(1 / 60)  # the first cycle, 1/60 s after /tf_static at the start
    assert Path(run.path / "bag" / "metadata.yaml").is_file()


def test_report_header_names_the_run_folder_and_the_scenario(run, tmp_path):
    """Two runs of one scenario must be told apart by their page: the heading names the folder."""
    page = build_report(run.path, tmp_path / "r.html", name="office-run").read_text(encoding="utf-8")
    assert "<title>RobChair run office-run</title>" in page
    assert re.search(r"<h1>RobChair run office-run\b", page)
    assert "run folder office-run · scenario synthetic_quarter_circle · backend sim · sim time s 1" in page


def test_pictures_and_key_metrics_come_before_the_full_metrics_table(run, tmp_path):
    """The page opens with a few key figures and the pictures; the full table (every flattened metric)
    is last, folded in a <details> element."""
    page = build_report(run.path, tmp_path / "r.html").read_text(encoding="utf-8")
    body = page[page.index("<body>") :]
    key, pictures = body.index('id="key-metrics"'), body.index('id="pictures"')
    details = body.index("<details>")
    assert key < pictures < details
    assert body.index('id="all-metrics"') > body.index('id="safety-stops"')
    # the key table is short and holds the route outcome; the full one every flattened metric
    key_rows = body[key:pictures].count("<tr><td>")
    assert 3 <= key_rows <= 16
    assert "<td>route.goal_reached</td><td>false</td>" in body[key:pictures]
    assert "<td>safety.stops (count)</td><td>2</td>" in body[key:pictures]
    full = body[details : body.index("</details>")]
    assert full.count("<tr><td>") == len(flatten_metrics(json.loads((run.path / "metrics.json").read_text())))
    assert body[:pictures].count("<tr><td>") == key_rows  # no other table row before any picture


def test_mapping_time_plot_marks_the_first_frame_and_scales_to_the_rest(run, tmp_path):
    """A first frame of 3800 ms (the kernels' compile) against later frames of 2.0-2.4 ms: the later
    frames set the axis (up to 1.15 x 2.4 ms, times the 8 % headroom), the first is its own trace,
    labelled with its time and drawn at the top edge."""
    import shutil

    folder = tmp_path / "run"
    shutil.copytree(run.path, folder)
    lines = (folder / "timeseries.csv").read_text().splitlines()
    k = next(i for i, line in enumerate(lines[1:], 1) if not line.endswith(","))
    lines[k] = lines[k].rsplit(",", 1)[0] + ",3800.0"
    (folder / "timeseries.csv").write_text("\n".join(lines) + "\n")
    page = build_report(folder).read_text(encoding="utf-8")
    traces = _plot_data(page, "time-plots")
    first = next(t for t in traces if t.get("name", "").startswith("first frame"))
    assert first["name"] == "first frame: 3800 ms (compile)"
    assert first["text"] == ["first frame 3800 ms (off scale)"]
    later = next(t for t in traces if t.get("name") == "mapping time")
    assert first["yaxis"] == later["yaxis"]
    layout = json.loads(
        re.search(
            r'Plotly\.newPlot\(\s*"time-plots",\s*\[.*?\],\s*(\{.*?\}),\s*\{"displaylogo', page, re.S
        ).group(1)
    )
    axis = layout["yaxis" + first["yaxis"][1:]]
    assert axis["range"] == pytest.approx([0.0, 1.15 * 2.4 * 1.08])
    assert first["y"] == [pytest.approx(1.15 * 2.4)]


def test_report_command_writes_the_page_and_prints_its_path(run, capsys):
    from robchair.cli import main

    (run.path / "report.html").unlink(missing_ok=True)
    assert main(["report", str(run.path)]) == 0
    assert capsys.readouterr().out == f"{run.path / 'report.html'}\n"
    assert (run.path / "report.html").stat().st_size > 1_000_000
    assert main(["report", str(run.path / "missing")]) == 2
    assert (
        capsys.readouterr().err
        == f"robchair report: error: {run.path / 'missing'}: not a run folder (no such directory)\n"
    )
