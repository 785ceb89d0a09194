"""The fan table's 4-word accesses (rows of 4 and 8 words) against the previous word-by-word kernel.

``fan_bits`` sets a run of bins with one or two branch-free 4-word accesses when a cell's row has 4 or 8
words, and ``FanJob`` pads rows of 5 to 7 words to 8 for it: the bits, the passage count and the
map's intervals must be those of the word-by-word kernel on unpadded rows.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from mapping import _evidence_kernels as E
from mapping import _frame_evidence
from mapping.grid import GridSpec
from mapping.probabilistic import EvidenceParams, ProbabilisticVHV
from tests.mapping.test_evidence_kernels import _random_case, _ref_fan_bits


def _case_with_rows(rng: np.random.Generator, nw: int) -> tuple[Any, ...]:
    """A random case of :func:`_random_case` whose bins fit rows of ``nw`` words but not of ``nw - 4``
    (so that runs cross the middle of an 8-word row), with its row width set to ``nw``."""
    while True:
        args = list(_random_case(rng))
        nbins = args[18]
        if (nw - 4) * 64 < nbins <= nw * 64:
            args[14] = nw
            return tuple(args)


@pytest.mark.parametrize("nw", [4, 8])
@pytest.mark.parametrize("seed", range(25))
def test_four_word_runs_equal_the_word_by_word_kernel(nw: int, seed: int) -> None:
    args = _case_with_rows(np.random.default_rng(1000 * nw + seed), nw)
    ni, nj = args[12], args[13]
    new = np.zeros(ni * nj * nw, np.uint64)
    ref = np.zeros(ni * nj * nw, np.uint64)
    assert E.fan_bits(*args, new) == _ref_fan_bits(*args, ref)
    assert np.array_equal(new, ref)
    assert ref.any()


def test_rows_of_five_to_seven_words_are_padded_to_eight_within_the_budget() -> None:
    assert [_frame_evidence._row_words(n, 64) for n in (1, 64, 65, 256, 257, 448, 449, 512, 513)] == [
        1,
        1,
        2,
        4,
        8,
        8,
        8,
        8,
        9,
    ]
    assert _frame_evidence._row_words(300, 7) == 5  # no room for the padding: rows as they are


def _tall_scene(rng: np.random.Generator) -> np.ndarray:
    """Walls 0-4 m high around a sensor at 1 m (fans spanning 400 bins of 1 cm: rows of 7 words)."""
    a = rng.uniform(0, 2 * np.pi, 40_000)
    d = rng.uniform(1.0, 3.5, a.shape[0])
    z = rng.uniform(0.0, 4.0, a.shape[0])
    pts = np.stack([d * np.cos(a), d * np.sin(a), z], axis=1)
    pts[rng.random(a.shape[0]) < 0.05] = np.nan
    return pts


def test_padded_rows_give_the_same_map_as_unpadded_rows(monkeypatch: pytest.MonkeyPatch) -> None:
    """A tall scene (rows of 7 words, padded to 8) mapped over three frames: every interval and
    log-odds as with rows of 7 words (the word-by-word path)."""
    widths: list[int] = []
    row_words = _frame_evidence._row_words

    def spy(nbins: int, budget: int) -> int:
        widths.append(row_words(nbins, budget))
        return widths[-1]

    def maps() -> list[np.ndarray]:
        rng = np.random.default_rng(3)
        m = ProbabilisticVHV(GridSpec(cell_size=0.05, size_x=10.0, size_y=10.0), 0.05, EvidenceParams())
        for k in range(3):
            m.insert(_tall_scene(rng), sensor_origin=np.array([0.03 * k, 0.0, 1.0]), max_range=6.0)
        s = m.intervals()
        return [np.asarray(getattr(s, f)).copy() for f in ("i", "j", "bottom", "top", "log_odds")]

    monkeypatch.setattr(_frame_evidence, "_row_words", spy)
    padded = maps()
    assert widths and set(widths) == {8}
    monkeypatch.setattr(_frame_evidence, "_row_words", lambda nbins, budget: (nbins + 63) // 64)
    plain = maps()
    assert all(np.array_equal(a, b) for a, b in zip(padded, plain, strict=True))
    assert padded[0].shape[0] > 1000
