"""The loop's kernel warm-up loads the kernels for the argument types of a real depth frame.

numba compiles a kernel once per argument type. The warm-up used to insert float64 points only, while
the frames reach the maps placed as read-only float32 with no-return rays: on a cold cache the first
frame then compiled the VHV build and the evidence kernels again inside the run (about 20 s; session 9).
"""

import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]

_CODE = textwrap.dedent(
    """
    import importlib, sys
    import numpy as np
    from numba.core.registry import CPUDispatcher
    from mapping.grid import GridSpec
    from mapping.probabilistic import make_map
    from robchair.perception_layers import _Placer, load_kernels, run_evidence_params

    kind = sys.argv[1]
    grid = GridSpec(cell_size=0.05, size_x=8.0, size_y=8.0)
    params = run_evidence_params() if kind == "probabilistic" else None
    names = ("_vhv_kernels", "_evidence_kernels", "_store_kernels", "_voxel_first")
    mods = [importlib.import_module("mapping." + m) for m in names]

    def signatures():
        return {f"{m.__name__}.{k}": len(v.signatures) for m in mods for k, v in vars(m).items()
                if isinstance(v, CPUDispatcher)}

    load_kernels(make_map(grid, 0.05, kind, params), 30.0, 4.0)
    before = signatures()
    # a frame as the perception stage hands it to a map (FrameInserter._insert_each)
    rng = np.random.default_rng(0)
    cam = rng.uniform([0.5, -1.0, -0.5], [3.0, 1.0, 0.5], (500, 3)).astype(np.float32)
    cam[::50] = np.nan
    t = np.eye(4)
    t[2, 3] = 1.2
    placer = _Placer(cam, np.array([[4.0, 0.0, 0.5], [4.0, 1.0, 0.8]], np.float32))
    m = make_map(grid, 0.05, kind, params)
    far = placer.far_points(t)
    if hasattr(m, "insert_frame"):
        m.insert_frame(placer.points(t), t[:3, 3], no_return_ends=far, stamp=0.1)
    else:
        m.insert(placer.points(t), sensor_origin=t[:3, 3])
    after = signatures()
    print("NEW", sorted(k for k in after if after[k] > before.get(k, 0)))
    print("USED", sum(after.values()))
    """
)


@pytest.mark.parametrize("kind", ["probabilistic", "thesis"])
def test_a_placed_frame_after_the_warm_up_needs_no_new_kernel_signature(kind: str) -> None:
    res = subprocess.run([sys.executable, "-c", _CODE, kind], cwd=ROOT, capture_output=True, text=True,
                         timeout=600)  # fmt: skip
    assert res.returncode == 0, res.stderr[-2000:]
    lines = dict(x.split(" ", 1) for x in res.stdout.splitlines() if x.startswith(("NEW", "USED")))
    assert int(lines["USED"]) > 3  # the kernels were found and used
    assert lines["NEW"] == "[]"
