"""The scripts behind BENCHMARKS.md's float32-floor, MAX_CELLS, packet-size, shadow-packet,
shadow-ray, drawn-light and light-map tables (scripts/) run and print the table they make: each runs at a small size as a
subprocess, exits 0 and prints a markdown table whose header and row labels are those of its table
in BENCHMARKS.md (found by the script's name on the table's source line).  Timed figures are checked
for their form only.
"""

import re

import pytest

from helpers.scripts import NUMBER, doc_table, needs, run_script

from gridrt.app.bench import occluded
from gridrt.app.bench.sides import MissingPeer

#: "a / b": a figure at each of two settings (threads, or precisions), either maybe in bold
PAIR = re.compile(r"(\*\*)?-?\d+(\.\d+)?(\*\*)? / (\*\*)?-?\d+(\.\d+)?(\*\*)?")


def check_labels(script, *args):
    """The rows of scripts/<script>'s table with ``args``, after checking its header and row labels
    against BENCHMARKS.md's."""
    header, rows = run_script(script, *args)
    doc_header, doc_rows = doc_table(script)
    assert header == doc_header
    assert [r[0] for r in rows] == [r[0] for r in doc_rows]
    return rows


def test_float32_floor_prints_its_table():
    rows = check_labels("float32_floor.py", "--size", "80x60")
    for r in rows:
        assert re.fullmatch(r"[\d,.]+", r[1]) and re.fullmatch(r"\d+( \([\d.]+ %\))?", r[2]), r
        assert re.fullmatch(r"\d\.\de[+-]\d\d", r[3]), r
    # the teapot's detail in float32 steps falls as the frame grows, 10x per 10x D
    steps = [float(r[1].replace(",", "")) for r in rows]
    assert all(a > b for a, b in zip(steps, steps[1:])), steps


@pytest.mark.slow  # (a subprocess that compiles the script's packet settings; the quick run keeps the other scripts)
def test_cast_max_cells_prints_its_table():
    rows = check_labels("cast_max_cells.py", "--size", "64", "--runs", "1", "--threads", "1,2")
    for r in rows:
        assert all(PAIR.fullmatch(c) for c in r[1:6]), r
        assert r[6] == "n/a" or PAIR.fullmatch(r[6]), r


@needs("lucy")
def test_packet_size_precision_prints_its_table():
    rows = check_labels("packet_size_precision.py", "--size", "64", "--renders", "1")
    for r in rows:
        assert all(PAIR.fullmatch(c) for c in r[1:]), r


def test_shadow_max_cells_prints_its_table():
    """The shipped scenes' rows (the script stops with an error when a value renders another image
    than the others): the table's header, its lights and shadow rays a pixel as figures, a time
    for every value."""
    header, rows = run_script("shadow_max_cells.py", "--scenes", "museum,cesium_man", "--size", "64x48",
                              "--frames", "1")
    doc_header, doc_rows = doc_table("shadow_max_cells.py")
    assert header == doc_header
    assert [r[0] for r in rows] == ["museum", "cesium_man"]
    assert {"museum", "cesium_man"} <= {r[0] for r in doc_rows}
    for r in rows:
        assert r[1].isdigit() and int(r[1]) >= 1 and NUMBER.fullmatch(r[2]), r
        assert all(c.isdigit() for c in r[3:]), r


def test_shadow_rays_prints_its_table():
    """A small mesh's shadow segments: the table's header, its figures in form, and every segment
    blocked as the single rays and the float64 brute force block it (the script counts those);
    where native Embree can be compiled (CI installs it), its columns with their fastest mode, and
    its verdicts those of gridrt but for rounding at an edge (at most 1 in 1,000 segments)."""
    header, rows = run_script("shadow_rays.py", "--scenes", "icosphere:1280:twist", "--size", "128", "--runs", "1",
                              "--warmup", "0", "--check", "300")
    doc_header, doc_rows = doc_table("shadow_rays.py")
    assert header == doc_header
    assert [r[0] for r in rows] == ["icosphere:1280:twist"] * 2 and [r[4] for r in rows] == ["1", "2"]
    try:
        occluded.build()
        native = True
    except MissingPeer:
        native = False
    mode = re.compile(NUMBER.pattern + r" \((1|p16|1M)\)")
    for r in rows:
        n = int(r[3].replace(",", ""))
        assert r[1] == "1,280" and r[2] == "1" and n > 1000, r
        assert NUMBER.fullmatch(r[5]) and (r[6] == "-" or NUMBER.fullmatch(r[6])), r
        assert r[11] == "0" and int(r[12]) >= 250 and r[13] == "0", r
        if native:
            assert mode.fullmatch(r[7]) and mode.fullmatch(r[8]) and NUMBER.fullmatch(r[10]), r
            assert all(int(k) <= n // 1000 for k in r[14].split(", ")), r
        else:
            assert r[7] == r[8] == r[10] == r[14] == "-", r


def test_light_samples_prints_its_table():
    """The museum (shipped) at 128x96: the table's header; the exact row off by nothing, each drawn
    mode's draws counted as asked, their mean off by less than one draw, its time that many frames."""
    header, rows = run_script("light_samples.py", "--scenes", "museum:0", "--size", "128", "--samples", "1,2",
                              "--draws", "8", "--runs", "1", "--warmup", "0")
    doc_header, doc_rows = doc_table("light_samples.py")
    assert header == doc_header
    assert "museum" in {r[0] for r in doc_rows}
    assert [(r[2], r[7]) for r in rows] == [("every light", "1"), ("1 drawn a pixel", "1"), ("1 drawn a pixel", "8"),
                                            ("2 drawn a pixel", "1"), ("2 drawn a pixel", "8")]
    assert rows[0][9:] == ["0.00", "0.00%", "0"] and all(r[1] == "2" and r[3] == "2" for r in rows)
    for one, mean in ((rows[1], rows[2]), (rows[3], rows[4])):
        assert NUMBER.fullmatch(one[4]) and NUMBER.fullmatch(one[6]) and float(one[6]) <= 2.0, one
        assert 0 < float(mean[9]) < float(one[9]), (one, mean)
        assert abs(float(mean[8]) - 8 * float(one[4])) <= 8, (one, mean)


def test_light_maps_prints_its_table():
    """The museum (shipped) at 128x96: the table's header and labels; both of its point lights
    mapped, some segments shown clear, and every frame of the two pipelines the same."""
    header, rows = run_script("light_maps.py", "--scenes", "museum:0", "--size", "128", "--threads", "1",
                              "--runs", "2")
    doc_header, doc_rows = doc_table("light_maps.py")
    assert header == doc_header
    assert "museum" in {r[0] for r in doc_rows}
    assert [r[:3] for r in rows] == [["museum", "2", "1"]]
    r = rows[0]
    assert NUMBER.fullmatch(r[3]) and NUMBER.fullmatch(r[4]) and NUMBER.fullmatch(r[5]), r
    assert 0 < float(r[7].rstrip("%")) <= 100 and 0 <= float(r[8].rstrip("%")) <= 100, r
    assert NUMBER.fullmatch(r[9]) and NUMBER.fullmatch(r[10]) and float(r[10]) > 0, r
    assert r[11].startswith("2 lights, ") and r[13] == "2 of 2", r


def test_character_frame_prints_its_table():
    """Cesium Man and Sydney (shipped) at 96x96, filling the frame: the table's header and labels;
    every mode's frame at least its build and trace, the material passes' time only where the
    mode has one, the shadow rays only with shadows, and most pixels hit."""
    header, rows = run_script("character_frame.py", "--scenes", "cesium_man,sydney", "--size", "96", "--threads", "1",
                              "--runs", "2", "--warmup", "0")
    doc_header, doc_rows = doc_table("character_frame.py")
    assert header == doc_header
    assert {r[3] for r in rows} == {r[3] for r in doc_rows} == {"lambert", "material", "material + shadows"}
    assert [(r[0], r[3]) for r in rows] == [(s, m) for s in ("cesium_man", "sydney")
                                            for m in ("lambert", "material", "material + shadows")]
    for r in rows:
        frame, fps, build, trace, shade = (float(x) for x in r[4:9])
        assert frame >= build + trace - 0.5 and abs(fps - 1e3 / frame) <= 0.1 * fps, r
        assert (shade == 0.0) == (r[3] == "lambert"), r
        assert float(r[9]) >= 0.9, r
        assert (float(r[10]) > 0) == (r[3] == "material + shadows"), r
