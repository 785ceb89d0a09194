"""The run report renders in a real browser (Debian's Chromium, headless) with no console errors.

Skipped when Chromium is not installed, unless ``ROBCHAIR_REQUIRE_BROWSER=1`` (set by ``.ci/run``, which
installs it): then a missing browser fails the test.
"""

from __future__ import annotations

import os

import pytest

from robchair.report import build_report
from tests.robchair.headless_chromium import find_chromium, open_page
from tests.robchair.synthetic_run import write_synthetic_run, write_timeseries

READY = (
    "document.readyState === 'complete' && document.querySelectorAll('.plotly-graph-div').length > 0 && "
    "Array.from(document.querySelectorAll('.plotly-graph-div')).every(d => d._fullLayout && "
    "d.querySelector('.main-svg'))"
)
PROBES = {
    "plots": "document.querySelectorAll('.plotly-graph-div').length",
    "rendered_plots": "Array.from(document.querySelectorAll('.plotly-graph-div'))"
    ".filter(d => d._fullLayout && d.querySelector('.main-svg')).length",
    # the 3D view draws on a WebGL canvas; plotly replaces it by a notice when WebGL is missing
    "gl_canvases": "document.querySelectorAll('#structures-3d .gl-container canvas').length",
    "webgl_notice": "document.body.innerText.includes('WebGL is not supported')",
    "time_traces": "document.querySelectorAll('#time-plots .scatterlayer .trace').length",
    "images_decoded": "Array.from(document.images).filter(i => i.complete && i.naturalWidth > 0).length",
    "images": "document.images.length",
}


@pytest.fixture(scope="module")
def chromium():
    path = find_chromium()
    if path is None:
        if os.environ.get("ROBCHAIR_REQUIRE_BROWSER") == "1":
            pytest.fail("ROBCHAIR_REQUIRE_BROWSER=1 but no chromium on PATH (apt-get install chromium)")
        pytest.skip("chromium is not installed (apt-get install chromium); ROBCHAIR_REQUIRE_BROWSER=1 fails")
    return path


def test_report_renders_in_headless_chromium_without_console_errors(tmp_path, chromium):
    run = write_synthetic_run(tmp_path / "run", 1.0)
    write_timeseries(run.path, run.cycles)
    page = build_report(run.path)
    res = open_page(chromium, page.resolve().as_uri(), PROBES, READY, timeout_s=240)
    v = res.values
    assert res.errors == []
    assert v["plots"] == 2 and v["rendered_plots"] == 2, v
    assert v["gl_canvases"] >= 1 and not v["webgl_notice"], v
    # v, w, commands, both wheels (commanded and measured), mapping time (the frames after the first,
    # and the first frame, with its one-off kernel load, as its own marked point) and the stop markers
    assert v["time_traces"] == 11, v
    assert v["images"] == 1 and v["images_decoded"] == 1, v


def test_the_browser_check_sees_a_broken_page(tmp_path, chromium):
    broken = tmp_path / "broken.html"
    broken.write_text(
        "<html><body><div class='plotly-graph-div'></div><script>console.error('no data');"
        "undefinedFunction();</script></body></html>"
    )
    loaded = "document.readyState === 'complete'"
    res = open_page(chromium, broken.as_uri(), {"plots": "1"}, loaded, timeout_s=60)
    assert [e.split("\n")[0] for e in res.errors] == [
        "console.error: no data",
        "exception: ReferenceError: undefinedFunction is not defined",
    ]
