"""`robchair map` builds on a pipeline of threads by default: the maps equal those of ``--serial-build``
(a real bag written by `robchair sim`), and a bad message in the middle of a bag fails as the serial
build fails (one line on stderr, exit code 2, no output)."""

from __future__ import annotations

import json
import threading

import numpy as np
import pytest

from mapping.io.bags import write_bag
from mapping.pointcloud2 import encode
from robchair.cli import main
from robchair.commands import _map_pipeline
from robchair.commands import map as map_command
from tests.robchair.test_cli_map_tf import PC2, TF, S, _column, _tf

OUTPUTS = ("map.pgm", "map.yaml", "vhv_boxes.ply", "voxels.ply")


def _summary_without_timing(out) -> dict:  # type: ignore[no-untyped-def]
    s = json.loads((out / "summary.json").read_text())
    s.pop("timing_s")
    s.pop("build_ms")
    s["parameters"].pop("build_ms", None)
    return s


def _same_outputs(a, b) -> None:  # type: ignore[no-untyped-def]
    for name in OUTPUTS:
        assert (a / name).read_bytes() == (b / name).read_bytes(), name
    assert _summary_without_timing(a) == _summary_without_timing(b)


@pytest.mark.parametrize("kept", [True, False], ids=["frames-kept", "bag-read-twice"])
def test_a_sim_bag_maps_to_the_same_outputs_on_the_pipeline_as_serially(sim_run, tmp_path, monkeypatch, kept):
    """The run's MCAP bag (depth clouds, their no-return rays, TF) as the run's map is rebuilt
    (probabilistic, decaying at each cloud's stamp). With the bag read twice, reading, placing and
    measuring are pipeline stages too."""
    if not kept:
        monkeypatch.setattr(map_command, "MAX_KEPT_POINTS", 1)
    stages: list[str] = []
    run_stages = _map_pipeline.run_stages

    def counted(items, stage_list, depth=_map_pipeline.QUEUE_DEPTH):  # type: ignore[no-untyped-def]
        stages.append(f"{len(stage_list)} stages")
        yield from run_stages(items, stage_list, depth)

    monkeypatch.setattr(_map_pipeline, "run_stages", counted)
    bag = sim_run / "bag"
    common = ["map", str(bag), "--map-kind", "probabilistic", "--no-pictures"]
    assert main([*common, "--serial-build", "--out", str(tmp_path / "serial")]) == 0
    assert stages == []
    assert main([*common, "--out", str(tmp_path / "pipeline")]) == 0
    # the extent pass (reading, placing, measuring), and the build (its first stage reading the bag
    # again on the stages of a second reading pass when the frames were not kept)
    assert stages == (["3 stages", "3 stages"] if kept else ["3 stages", "4 stages", "3 stages"])
    _same_outputs(tmp_path / "serial", tmp_path / "pipeline")
    s = json.loads((tmp_path / "pipeline" / "summary.json").read_text())
    assert (
        s["frames"] >= 5 and s["no_return"]["rays_inserted"] > 0 and s["tf"]["clouds_placed"] == s["frames"]
    )


def _bag_with_a_bad_cloud(path):  # type: ignore[no-untyped-def]
    """Clouds at t = 1 .. 6 s under a static TF; the fourth lacks its z field."""
    msgs = [("/tf_static", TF, 1 * S, _tf(False, 1 * S, "odom", "laser", (0.0, 0.0, 0.3), 0.0))]
    for k in range(6):
        stamp = (1 + k) * S
        msg = _column("laser", stamp, 1.0 + 0.1 * k, 0.0, False)
        if k == 3:
            bad = encode(np.zeros((3, 3), np.float32), frame_id="laser", stamp_ns=stamp)
            bad.fields = bad.fields[:2]
            from mapping.io.bags import to_ros_pointcloud2

            msg = to_ros_pointcloud2(bad, ros2=False)
        msgs.append(("/points", PC2, stamp, msg))
    return write_bag(path, msgs, ros2=False)


@pytest.mark.parametrize("size", [[], ["--size", "6", "6"]], ids=["extent-pass", "build-pass"])
def test_a_bad_message_in_the_middle_of_a_bag_fails_as_the_serial_build_does(tmp_path, capsys, size):
    bag = _bag_with_a_bad_cloud(tmp_path / "bad.bag")
    errors = []
    for mode, extra in (("serial", ["--serial-build"]), ("pipeline", [])):
        out = tmp_path / mode
        argv = ["map", str(bag), "--map-kind", "probabilistic", "--no-pictures", "--out", str(out)]
        assert main([*argv, *size, *extra]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1, err
        errors.append(err[0])
        assert not out.exists()
        assert not any(p.name.startswith(f".{mode}.") for p in tmp_path.iterdir())
    assert errors[0] == errors[1] and "PointCloud2 has no z field" in errors[0]
    assert not [t for t in threading.enumerate() if t.name.startswith("map-stage")]


def test_a_stage_that_fails_stops_the_pipeline_after_yielding_the_items_before_it():
    def second(x: int) -> int:
        if x == 5:
            raise ValueError("bad item 5")
        return 10 * x

    got = []
    with pytest.raises(ValueError, match="bad item 5"):
        for y in _map_pipeline.run_stages(range(100), [lambda x: x + 1, second], depth=2):
            got.append(y)
    assert got == [10, 20, 30, 40]
    assert not [t for t in threading.enumerate() if t.name.startswith("map-stage")]
    # the caller stopping early stops the stages too
    gen = _map_pipeline.run_stages(iter(range(10**6)), [lambda x: x], depth=2)
    assert next(gen) == 0
    gen.close()
    assert not [t for t in threading.enumerate() if t.name.startswith("map-stage")]


def test_the_callers_thread_only_updates_the_store_the_free_intervals_come_from_a_stage(
    sim_run, tmp_path, monkeypatch
):
    """The in-order stage (the caller's thread) is the store update alone: every frame's fans are
    marked and its free intervals extracted on stage threads, ahead of it."""
    from mapping._frame_evidence import PreparedFrame

    threads: dict[str, list[str]] = {"mark_fans": [], "extract_free": []}
    for name in threads:
        method = getattr(PreparedFrame, name)

        def recorded(self, _method=method, _name=name):  # type: ignore[no-untyped-def]
            if self.evidence["fans"] is not None:  # the call that does the work (later ones return)
                threads[_name].append(threading.current_thread().name)
            return _method(self)

        monkeypatch.setattr(PreparedFrame, name, recorded)
    out = tmp_path / "pipeline"
    argv = ["map", str(sim_run / "bag"), "--map-kind", "probabilistic", "--no-pictures", "--out", str(out)]
    assert main(argv) == 0
    frames = json.loads((out / "summary.json").read_text())["frames"]
    assert len(threads["extract_free"]) >= frames >= 5
    main_thread = threading.main_thread().name
    assert all(t.startswith("map-stage") for t in threads["mark_fans"] + threads["extract_free"]), threads
    assert main_thread not in threads["extract_free"]
