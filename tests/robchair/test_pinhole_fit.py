"""The pinhole fit of a depth camera's first frame is made once per process (robchair.perception_depth)."""

from __future__ import annotations

import threading

import numpy as np
import pytest

import robchair.perception_depth as pdepth


def _frame(h: int = 120, w: int = 160, depth: float = 2.0) -> np.ndarray:
    """An organized float32 cloud of a wall at x = ``depth`` through a pinhole (fx = fy = 100)."""
    u = (np.arange(w) + 0.5 - w / 2) / 100.0
    v = (np.arange(h) + 0.5 - h / 2) / 100.0
    pts = np.empty((h, w, 3), dtype=np.float32)
    pts[..., 0] = depth
    pts[..., 1] = -u[None, :] * depth
    pts[..., 2] = -v[:, None] * depth
    pts[::3, ::4] = np.nan  # no returns there
    return pts


@pytest.fixture
def fits(monkeypatch: pytest.MonkeyPatch) -> list[int]:
    """The sizes of the frames actually fitted, with the memo emptied."""
    monkeypatch.setattr(pdepth, "_FITS", {})
    made: list[int] = []
    fit = pdepth._fit_pinhole_rays

    def counted(pts: np.ndarray, stride: int) -> np.ndarray | None:
        made.append(pts.size)
        return fit(pts, stride)

    monkeypatch.setattr(pdepth, "_fit_pinhole_rays", counted)
    return made


def test_the_same_frame_is_fitted_once_and_gives_the_same_rays(fits: list[int]) -> None:
    pts = _frame()
    first = pdepth.pinhole_rays(pts, 4)
    assert first is not None and first.shape == (30, 40, 3) and not first.flags.writeable
    again = pdepth.pinhole_rays(pts.copy(), 4)  # the same bytes: the perception stage, then the recorder
    assert again is first and len(fits) == 1
    unmemoized = pdepth._fit_pinhole_rays(pts, 4)
    assert unmemoized is not None and np.array_equal(first, unmemoized)
    assert np.allclose(np.linalg.norm(first, axis=-1), 1.0)


def test_another_frame_or_stride_is_fitted_again(fits: list[int]) -> None:
    pts = _frame()
    pdepth.pinhole_rays(pts, 4)
    other = pts.copy()
    other[5, 7, 0] += 1e-3  # one point moved: another frame
    assert pdepth.pinhole_rays(other, 4) is not None
    assert pdepth.pinhole_rays(pts, 2) is not None
    assert pdepth.pinhole_rays(pts[:, :80], 4) is not None
    assert len(fits) == 4
    assert pdepth.pinhole_rays(np.full((20, 20, 3), np.nan, dtype=np.float32), 4) is None  # too few
    assert pdepth.pinhole_rays(np.full((20, 20, 3), np.nan, dtype=np.float32), 4) is None
    assert len(fits) == 5


def test_two_threads_fitting_the_same_frame_at_once_fit_it_once(fits: list[int]) -> None:
    """The perception stage's thread and the recorder (the drive loop's thread) take the first frame at
    the same time."""
    pts = _frame(480, 640)
    start = threading.Barrier(2)
    got: list[np.ndarray | None] = []

    def take() -> None:
        start.wait()
        got.append(pdepth.pinhole_rays(pts, 4))

    threads = [threading.Thread(target=take) for _ in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert len(fits) == 1 and got[0] is got[1] and got[0] is not None


def test_the_memo_keeps_a_few_fits_only(fits: list[int]) -> None:
    for k in range(pdepth._MAX_FITS + 3):
        pdepth.pinhole_rays(_frame(depth=1.0 + k), 4)
    assert len(pdepth._FITS) == pdepth._MAX_FITS
