"""The last bad inputs, through the real command line (a subprocess per case).

A bad input exits with status 2 and prints exactly one line, ``gridrt: error: ...`` naming the
problem: no traceback, no numpy RuntimeWarning before it.  A warning is one plain line
``gridrt: warning: ...`` (plain numbers, no Python source line).  The only other line allowed on
stderr is the notice that numba kernels are being compiled (printed on a cold cache).
"""

import json
import struct
import warnings

import numpy as np
import pytest

from helpers.cli import gridrt, one_error, stderr_lines
from helpers.scene_files import AFF_OK, Builder, md2_bytes, write_aff, write_arm


def dump(tmp_path, *args):
    return gridrt("dump", "--frames", "1", "--size", "8x8", "--no-progress", "--out", str(tmp_path / "out"), *args)


# ----------------------------------------------------------------------------- camera


@pytest.mark.parametrize("fov", ["0", "inf", "-inf", "nan", "180"])
def test_bad_fov_with_the_automatic_camera(tmp_path, fov):
    """Automatic framing once crashed with ZeroDivisionError (fov 0) or 'math domain error' (inf), and
    blamed the eye for a NaN fov."""
    line = one_error(dump(tmp_path, "--scene", "icosphere", f"--fov={fov}"),
                     "camera fov must be between 0 and 180 degrees")
    assert "eye" not in line


def test_bad_fov_with_an_explicit_camera_and_a_too_narrow_one(tmp_path):
    line = one_error(dump(tmp_path, "--scene", "icosphere", "--eye", "0,0,5", "--target", "0,0,0", "--fov=nan"),
                     "camera fov must be between 0 and 180 degrees", "got nan")
    assert "eye" not in line
    one_error(dump(tmp_path, "--scene", "icosphere", "--fov=1e-300"), "camera fov 1e-300 is too narrow to frame")


def test_eye_far_beyond_the_coordinate_limit_blames_the_eye(tmp_path):
    line = one_error(dump(tmp_path, "--scene", "icosphere", "--eye", "1e308,0,0", "--target", "0,0,0"),
                     "camera eye (1e+308, 0, 0) is beyond the coordinate limit of 1e+30")
    assert "up vector" not in line and "parallel" not in line


# ----------------------------------------------------------------------------- glTF


def _glb_v1(path):
    """A binary glTF 1.0 file (KHR_binary_glTF: container version 1, JSON scene, content format 0)."""
    js = json.dumps({"asset": {"version": "1.0"}, "nodes": {"n": {}}, "scenes": {"s": {"nodes": ["n"]}},
                     "scene": "s"}).encode()
    js += b" " * (-len(js) % 4)
    path.write_bytes(struct.pack("<4sIIII", b"glTF", 1, 20 + len(js), len(js), 0) + js)
    return path


def _gltf_edit(tmp_path, name, edit):
    p = write_arm(tmp_path / name, "u8")
    tree = json.loads(p.read_text())
    edit(tree)
    p.write_text(json.dumps(tree))
    return p


GLTF1 = {
    "number-1.0": lambda t: t.update(asset={"version": 1.0}),  # once: "'nodes' is not a list" (for glTF 1.0 files)
    "number-1": lambda t: t.update(asset={"version": 1}),
    "string-1.0": lambda t: t.update(asset={"version": "1.0"}),
    "1.0-layout-no-version": lambda t: t.update(asset={}, nodes={"n": t["nodes"][0]}),
}


@pytest.mark.parametrize("case", list(GLTF1) + ["glb-container-1"])
def test_gltf_1_is_always_named(tmp_path, case):
    p = _glb_v1(tmp_path / "old.glb") if case == "glb-container-1" else _gltf_edit(tmp_path, "old.gltf", GLTF1[case])
    line = one_error(dump(tmp_path, "--scene", str(p)), f"{p}: glTF 1.0 is not supported")
    assert "is not a list" not in line


def test_non_indexed_primitive_message_does_not_talk_of_indices(tmp_path):
    b = Builder()
    m = b.mesh(np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]], np.float32), [0, 1, 2])
    b.node(root=True, mesh=m)
    p = b.save(tmp_path / "flat.gltf")
    tree = json.loads(p.read_text())
    del tree["meshes"][0]["primitives"][0]["indices"]  # 4 vertices, no index list: not whole triangles
    p.write_text(json.dumps(tree))
    line = one_error(dump(tmp_path, "--scene", str(p)), "mesh 0 primitive 0: 4 vertices is not a multiple of 3")
    assert "indices" not in line


# ----------------------------------------------------------------------------- counts and warnings


@pytest.mark.slow  # (the largest icosphere, 5,242,880 triangles, built and rendered: about 12 s of CPU)
def test_icosphere_count_beyond_the_largest_says_what_it_made(tmp_path):
    r = dump(tmp_path, "--scene", "icosphere", "--count", "1000000000")
    assert r.returncode == 0, r.stderr[-2000:]
    assert stderr_lines(r) == ["gridrt: warning: icosphere: count 1,000,000,000 is beyond the largest icosphere "
                               "(20 x 4^9); made 5,242,880 triangles"], r.stderr
    assert "5242880 triangles" in r.stdout


def test_marbles_count_beyond_its_limit_is_refused(tmp_path):
    one_error(dump(tmp_path, "--scene", "marbles", "--count", "60000000"),
              "marbles: triangle count must be between 322 and 50,000,000, got 60000000")


def test_light_samples_without_shadows_warn_in_one_line(tmp_path):
    """--light-samples draws the lights of shadow rays: without --shadows the frame is the exact
    one, and the command says so."""
    r = dump(tmp_path, "--scene", "icosphere", "--light-samples", "2")
    assert r.returncode == 0, r.stderr[-2000:]
    assert stderr_lines(r) == ["gridrt: warning: --light-samples 2 draws the lights of shadow rays: it has no effect "
                               "until shadows are on (--shadows)"], r.stderr


def test_cell_cap_warning_is_one_plain_line(tmp_path):
    """Python's default format printed 'pipeline.py:91: GridCapWarning: ... dims (np.int64(8), ...)' and
    the source line under it."""
    r = dump(tmp_path, "--scene", "icosphere", "--max-cells", "512")
    assert r.returncode == 0, r.stderr[-2000:]
    assert stderr_lines(r) == ["gridrt: warning: grid resolution capped at max_cells=512 (density 4 x 5120 "
                               "triangles asked for more); using dims 8 x 8 x 8"], r.stderr


def test_main_restores_the_warning_format():
    """The CLI's one-line format is installed only while main() runs (main may be called in-process)."""
    from gridrt.app.__main__ import main

    before = warnings.showwarning
    assert main(["strategies"]) == 0
    assert warnings.showwarning is before


# ----------------------------------------------------------------------------- malformed files


PLY_HEAD = ("ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
            "element face 1\nproperty list uchar int vertex_indices\nend_header\n")


def _md2_inf(tmp_path):
    p, raw = md2_bytes(tmp_path)
    struct.pack_into("<f", raw, 68 + 36, float("inf"))
    p.write_bytes(bytes(raw))
    return p


#: name -> (writer(tmp_path) -> path, words of the error).  Those marked (*) printed numpy
#: RuntimeWarnings (overflow / invalid value in cast, multiply, norm) before their error.
MALFORMED = {
    "obj-huge": (lambda d: _text(d / "huge.obj", "v 0 0 0\nv 1e300 0 0\nv 0 1 0\nf 1 2 3\n"), ["beyond 1e30"]),
    "off-huge": (lambda d: _text(d / "huge.off", "OFF\n3 1 0\n0 0 0\n1e300 0 0\n0 1e300 0\n3 0 1 2\n"),
                 ["beyond 1e30"]),
    "ply-float32-overflow": (lambda d: _text(d / "big.ply", PLY_HEAD + "0 0 0\n1e39 0 0\n0 1 0\n3 0 1 2\n"),  # (*)
                             ["NaN or infinity"]),
    "ply-nan-index": (lambda d: _text(d / "nanidx.ply", PLY_HEAD + "0 0 0\n1 0 0\n0 1 0\n3 0 nan 2\n"),  # (*)
                      ["face index"]),
    "stl-huge": (lambda d: _text(d / "huge.stl", "solid s\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\n"  # (*)
                                 "vertex 1e300 0 0\nvertex 0 1e300 0\nendloop\nendfacet\nendsolid s\n"),
                 ["beyond 1e30"]),
    "gltf-short-buffer": (lambda d: _gltf_edit(d, "short.gltf", lambda t: t["accessors"][0].update(count=10_000)),
                          ["need 120000 bytes"]),
    "aff-huge-tcb": (lambda d: write_aff(d, AFF_OK.replace("2 0 1 0 180  0 0 0", "2 0 1 0 180  1e300 0 0")),  # (*)
                     ["rot keys of 'spin'", "not finite"]),
    "md2-inf-scale": (_md2_inf, ["non-finite"]),
}


def _text(path, text):
    path.write_text(text)
    return path


@pytest.mark.parametrize("name", list(MALFORMED))
def test_malformed_file_prints_one_clean_error(tmp_path, name):
    writer, words = MALFORMED[name]
    p = writer(tmp_path)
    line = one_error(dump(tmp_path, "--scene", str(p)), *words)
    assert line.startswith(f"gridrt: error: {p}: "), line
