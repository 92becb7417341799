"""The memory-traffic model and the streaming kernels behind `gridrt bench build`'s bandwidth
section (engine/grid/traffic.py).

The model is checked against byte counts worked out by hand for a grid whose every number is
known; the streaming kernels against numpy on arrays whose sizes do not split evenly.
"""

import numpy as np
import pytest

from gridrt.errors import InputError
from gridrt.grid import GridParams, build_grid
from gridrt.grid.traffic import stage_bytes, stream_bandwidth, stream_copy, stream_read, stream_write
from gridrt.threads import use_threads


def _two_cell_scene():
    """Two triangles in a 2x1x1 grid: triangle 0 inside cell 0, triangle 1 across both cells."""
    return np.array([[[0.1, 0.1, 0.5], [0.3, 0.1, 0.5], [0.1, 0.3, 0.5]],
                     [[0.1, 0.6, 0.5], [1.9, 0.6, 0.5], [0.1, 0.9, 0.5]]], np.float32)


@pytest.mark.parametrize("strategy", ["serial", "counting", "sort_middle"])
def test_stage_bytes_hand_counted(strategy):
    tris = _two_cell_scene()
    # density 1 over 2 triangles and an extent of 1.8 x 0.8 x 0 -> 2 x 1 x 1 cells (flat z axis)
    g = build_grid(tris, GridParams(strategy=strategy, threads=2, density=1.0, macro=1))
    st = g.stats
    assert (st["dims"], st["references"], st["cells"]) == ("2x1x1", 3, 2)
    F, R, C = 2, 3, 2
    got = stage_bytes(st)
    assert got["bounds_ms"] == 36 * F
    assert got["clear_ms"] == 0  # a fresh build clears nothing
    # macro size 1: each of the 2 macro cells looks at its one cell; 1 flag byte each
    assert got["macro_ms"] == 4 * 2 + 2
    if strategy == "counting":
        assert got["ranges_ms"] == (36 + 24) * F
        assert got["count_ms"] == 2 * 24 * F + 8 * R + 4 * R
        assert got["scan_ms"] == 3 * 4 * C
        assert got["scatter_ms"] == 24 * F + 12 * R
    elif strategy == "sort_middle":
        # cells are one layer deep (z), so every triangle is in bucket 0 only: B = F
        assert st["bucket_entries"] == 2
        assert got["bucket_ms"] == (36 + 24) * F + 4 * 2
        assert got["count_ms"] == 28 * 2 + 8 * R
        assert got["scatter_ms"] == 28 * 2 + 8 * R + 4 * R
    else:
        assert got["count_ms"] == 24 * F + 8 * R
        assert got["scan_ms"] == 2 * 4 * C
        assert got["scatter_ms"] == 24 * F + 12 * R


def test_stage_bytes_not_modelled():
    tris = _two_cell_scene()
    assert stage_bytes(build_grid(tris, GridParams(strategy="sort_first")).stats) is None
    assert stage_bytes(build_grid(tris, GridParams(strategy="serial", insert="exact")).stats) is None


@pytest.mark.parametrize("threads", [1, 2, 3, 7])
@pytest.mark.parametrize("n", [1, 5, 1000, 100_003])
def test_stream_kernels(threads, n):
    use_threads(min(threads, 2))
    rng = np.random.default_rng(n)
    a = rng.integers(-1000, 1000, n).astype(np.int32)
    out = np.zeros(threads, np.int64)
    stream_read(a, threads, out)
    assert out.sum() == a.astype(np.int64).sum()
    b = np.zeros(n, np.int32)
    stream_copy(a, b, threads)
    assert np.array_equal(a, b)
    stream_write(b, threads, np.int32(7))
    assert (b == 7).all()


def test_stream_bandwidth_shape_and_errors():
    bw = stream_bandwidth(1, (1, 2), runs=1)
    assert set(bw) == {1, 2}
    assert all(set(d) == {"read", "write", "copy"} and all(np.isfinite(v) and v > 0 for v in d.values())
               for d in bw.values())
    with pytest.raises(InputError, match="mib"):
        stream_bandwidth(0)
    with pytest.raises(InputError, match="runs"):
        stream_bandwidth(1, runs=0)
