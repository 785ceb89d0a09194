"""The structure-keeping thinning: the kept points build the very same VHV structures as the whole cloud
(what makes a thinned bag map back to the run's map), with fewer points; a voxel filter does not."""

from __future__ import annotations

import numpy as np
import pytest

from mapping.grid import GridSpec, voxel_filter
from mapping.thinning import structure_keeping_indices
from mapping.vhv import VHVMap


def _structures(spec: GridSpec, points: np.ndarray) -> tuple[np.ndarray, ...]:
    m = VHVMap(spec, 0.05)
    m.insert(points)
    s = m.structures()
    return tuple(np.asarray(getattr(s, f)) for f in ("i", "j", "bottom", "top"))


@pytest.mark.parametrize("seed", [0, 1])
def test_kept_points_build_the_same_structures_as_the_whole_cloud(seed: int) -> None:
    rng = np.random.default_rng(seed)
    spec = GridSpec(0.05, 4.0, 4.0)
    p = np.concatenate(
        [rng.uniform([-2, -2, 0], [2, 2, 2], (60_000, 3)), rng.uniform([-1, -1, 0], [1, 1, 0.3], (60_000, 3))]
    ).astype(np.float32)
    p[::50] = np.nan
    p[1::97] = (9.0, 9.0, 1.0)  # outside the grid: left out
    idx = structure_keeping_indices(p, spec, 0.05)
    assert len(idx) < 0.8 * len(p) and np.all(np.diff(idx) > 0)
    whole, kept = _structures(spec, p), _structures(spec, p[idx])
    assert all(np.array_equal(a, b) for a, b in zip(whole, kept, strict=True))
    # one point per 5 cm voxel (the bag's former thinning) changes the structures
    vox = _structures(spec, voxel_filter(p, 0.05))
    assert not all(a.shape == b.shape and np.array_equal(a, b) for a, b in zip(whole, vox, strict=True))


def test_bad_input_is_refused_naming_it() -> None:
    with pytest.raises(ValueError, match="points_world"):
        structure_keeping_indices(np.zeros((3, 2)), GridSpec(0.05, 1.0, 1.0), 0.05)
    with pytest.raises(ValueError, match="tolerance"):
        structure_keeping_indices(np.zeros((3, 3)), GridSpec(0.05, 1.0, 1.0), 0.0)
