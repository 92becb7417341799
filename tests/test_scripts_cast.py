"""The scripts behind BENCHMARKS.md's single-ray, cast-order, density, all-hits and origin-order tables
(scripts/) run and print the table they make: each runs at a small size as a subprocess, exits 0 and prints a
markdown table whose header and row labels are those of its table in BENCHMARKS.md (found by the
script's name on the table's source line).  The figures are timings: only their form is checked.
"""

import importlib.util
import json
import re

import numpy as np
import pytest

from helpers.scripts import NUMBER, REPO, doc_table, first_table, needs, run_script


def without_hit(label):
    """A single-ray row label without its measured hit fraction: "Lucy 100k twisted, fill"."""
    m = re.fullmatch(r"(.*) \(hit (\d\.\d\d)\)", label)
    assert m, label
    return m.group(1)


def check_table(script, args, keep=lambda label: True, label=lambda cell: cell, n_labels=1):
    """scripts/<script> run with ``args`` prints its BENCHMARKS.md table's header and the rows whose
    first cell passes ``keep``, in its order: their first ``n_labels`` cells the same (the first
    through ``label``), the others numbers (or "a, b" pairs of numbers)."""
    header, rows = run_script(script, *args)
    doc_header, doc_rows = doc_table(script)
    assert header == doc_header

    def labels(r):
        return [label(r[0]), *r[1:n_labels]]

    assert [labels(r) for r in rows] == [labels(r) for r in doc_rows if keep(r[0])]
    assert rows and all(NUMBER.fullmatch(x) for r in rows for c in r[n_labels:] for x in c.split(", ")), rows


def cesium(label):
    return label.startswith("Cesium Man 4.7k,")


@needs("cesium")
def test_single_ray_dda_prints_its_table_shipped_scene():
    """Its Cesium Man rows alone (the scene assets/ ships: runs in a clone without the data set)."""
    check_table("single_ray_dda.py", ["--size", "16", "--runs", "1", "--scenes", "cesium"], cesium, without_hit)


@needs("cesium")
def test_a_script_keeps_what_it_prints_with_out(tmp_path):
    """--out keeps the printed table in OUT/summary.md (what BENCHMARKS.md's tables are checked
    against) under the machine record, and OUT/machine.json names the command line."""
    out = tmp_path / "kept"
    printed = []
    args = ["--size", "16", "--runs", "1", "--scenes", "cesium", "--out", str(out)]
    header, rows = run_script("single_ray_dda.py", *args, printed=printed)
    assert f"wrote {out}/summary.md, machine.json" in printed[0]
    summary = (out / "summary.md").read_text(encoding="utf-8").split("\n")
    assert summary[0] == "# scripts/single_ray_dda.py" and "## Machine" in summary
    assert first_table(summary[summary.index("## Output"):])[:2] == (header, rows)
    machine = json.loads((out / "machine.json").read_text(encoding="utf-8"))
    assert machine["command"].split() == ["python", str(REPO / "scripts" / "single_ray_dda.py"), *args]
    assert machine["cpu"] and machine["date"][:4].isdigit()


@needs("cesium", "lucy")
def test_single_ray_dda_prints_its_table():
    check_table("single_ray_dda.py", ["--size", "16", "--runs", "1"], label=without_hit)


@needs("cesium")
def test_cast_ray_order_prints_its_table_shipped_scene():
    """Its Cesium Man rows alone (the scene assets/ ships: runs in a clone without the data set)."""
    check_table("cast_ray_order.py", ["--size", "64", "--runs", "1", "--scenes", "cesium"], cesium)


@needs("cesium", "lucy")
def test_cast_ray_order_prints_its_table():
    check_table("cast_ray_order.py", ["--size", "64", "--runs", "1"])


@needs("kitchen", "robots")
def test_two_level_densities_prints_its_table():
    check_table("two_level_densities.py", ["--size", "16", "--runs", "1", "--warmup", "0"], n_labels=2)


def test_doc_table_finds_each_script_once():
    """The lookup the tests above rely on: each script's table by its name, and none for a name
    no source line runs."""
    for script in ("single_ray_dda.py", "cast_ray_order.py", "two_level_densities.py"):
        header, rows = doc_table(script)
        assert len(header) >= 3 and rows and all(len(r) == len(header) for r in rows)
    with pytest.raises(AssertionError):
        doc_table("no_such_script.py")


@pytest.mark.slow
def test_all_hits_peers_prints_its_table():
    """The all-hits table at a small size: BENCHMARKS.md's header, a row a ray set, gridrt's counts
    even for every ray (each starts outside the closed icosphere: its crossings pair up), and the
    peers' columns either measured (on random rays they agree with gridrt on every ray) or n/a
    where a peer is not installed."""
    header, rows = run_script("all_hits_peers.py", "--sizes", "1280", "--rays", "3000", "--runs", "1")
    doc_header, _ = doc_table("all_hits_peers.py")
    assert header == doc_header and [r[1] for r in rows] == ["3,000 random", "3,000 at vertices"]
    for r in rows:
        assert r[0] == "icosphere 1.3k" and 1.0 < float(r[2]) < 3.0, r
        assert r[3].isdigit() and r[4].isdigit(), r
        assert r[5:7] == ["n/a", "n/a"] or (r[5].isdigit() and r[6].isdigit()), r
        assert r[7] == "n/a" or r[7].isdigit(), r
        even, agree = r[8].split(", "), r[9].split(", ")
        assert even[0] == "1.0000", r
        if r[1].endswith("random"):
            assert all(x in ("1.0000", "n/a") for x in even + agree), r


@pytest.mark.slow
def test_contains_order_prints_its_table():
    """The origin-order table at a small size: BENCHMARKS.md's header, a row a point count and thread
    count, the times as numbers (the script itself stops when the two orders' verdicts differ)."""
    header, rows = run_script("contains_order.py", "--sizes", "1280", "--points", "3000,5000", "--threads", "1,2",
                              "--runs", "1")
    doc_header, _ = doc_table("contains_order.py")
    assert header == doc_header
    assert [r[:3] for r in rows] == [["icosphere 1.3k", p, t] for t in "12" for p in ("3,000", "5,000")]
    assert all(NUMBER.fullmatch(c) for r in rows for c in r[3:]), rows


@pytest.mark.slow
def test_interleaved_rays_prints_its_table():
    """The interleaved-rays table at a small size: BENCHMARKS.md's header, a row a thread count,
    Mrays/s and ratios as numbers, and every ray's hit the same both ways."""
    header, rows = run_script("interleaved_rays.py", "--size", "32", "--runs", "1", "--scenes", "icosphere:1280",
                              "--threads", "1,2")
    doc_header, _ = doc_table("interleaved_rays.py")
    assert header == doc_header
    assert [r[:2] for r in rows] == [["icosphere 1.3k, random", "1"], ["icosphere 1.3k, random", "2"]]
    assert all(NUMBER.fullmatch(c) for r in rows for c in r[2:5]) and all(r[5] == "yes" for r in rows), rows


def _script_module(monkeypatch, name):
    monkeypatch.syspath_prepend(str(REPO / "scripts"))
    spec = importlib.util.spec_from_file_location(name, REPO / "scripts" / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_lidar_native_lays_the_sweep_out_as_tiles(monkeypatch):
    """The LiDAR sweep as the harness's square image: each 8x8 tile holds 8 neighbouring channels of
    8 neighbouring columns, every ray of the sweep is in the tiles exactly once, and the tiles past
    the sweep repeat the first ones (their fraction the one the script scales native's cast by)."""
    lidar = _script_module(monkeypatch, "lidar_native")
    channels, columns = 16, 40                      # 2 x 5 groups: a 4 x 4 image of tiles, 6 repeated
    res, index, repeated = lidar.tile_layout(channels, columns)
    assert res == 32 and abs(repeated - 6 / 16) < 1e-12
    img = index.reshape(res, res)
    col, ch = np.divmod(img, channels)
    tiles = [(ty, tx) for ty in range(4) for tx in range(4)]
    seen = []
    for k, (ty, tx) in enumerate(tiles):
        c, a = ch[8 * ty:8 * ty + 8, 8 * tx:8 * tx + 8], col[8 * ty:8 * ty + 8, 8 * tx:8 * tx + 8]
        assert (np.diff(c, axis=0) == 1).all() and (np.diff(a, axis=1) == 1).all() and c[0, 0] % 8 == 0 == a[0, 0] % 8
        if k < 10:
            seen.append(img[8 * ty:8 * ty + 8, 8 * tx:8 * tx + 8].ravel())
        else:   # a repeat of tile k - 10
            py, px = tiles[k - 10]
            assert (img[8 * ty:8 * ty + 8, 8 * tx:8 * tx + 8] == img[8 * py:8 * py + 8, 8 * px:8 * px + 8]).all()
    assert np.array_equal(np.sort(np.concatenate(seen)), np.arange(channels * columns))


@pytest.mark.slow
def test_lidar_native_prints_its_table(harness):
    """The LiDAR-step table at a small size against the compiled harness: BENCHMARKS.md's header,
    one row a thread count, times that are numbers, and the same triangle as native rtcIntersect1
    for (nearly) every beam."""
    header, rows = run_script("lidar_native.py", "--triangles", "5000", "--channels", "16", "--columns", "64",
                              "--frames", "2", "--binary", str(harness))
    doc_header, _ = doc_table("lidar_native.py")
    assert header == doc_header and [r[3] for r in rows] == ["1", "2"]
    for r in rows:
        assert r[:3] == ["icosphere 5.1k", "5,120", "1,024"], r
        assert all(NUMBER.fullmatch(c) for c in r[4:12]), r
        assert float(r[12]) > 0.999, r
