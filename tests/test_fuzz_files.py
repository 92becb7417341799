"""Malformed, truncated and mutated scene files: every failure is a SceneFileError naming the file.

Hand-written broken files check the message for each kind of problem; hypothesis then truncates
and mutates valid files of every format (glTF .glb/.gltf, BART .aff, MD2, OBJ frame folders, static
OBJ/OFF/PLY/STL): each mutant either loads into finite triangles or raises SceneFileError whose path
is the file (or a file it refers to), never another exception, within a time bound per example, and
without a numpy RuntimeWarning (the command line would print it before its one-line error).
"""

import json
import re
import struct
import warnings

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import gridrt  # noqa: F401  (sets numba's thread count before numba loads)
from gridrt.errors import SceneFileError
from gridrt.scene import make_scene

from helpers.scene_files import (AFF_OK, GRID_F, OCTA_F, OCTA_T, OCTA_V, PART, TRI_F, TRI_V, Builder,  # noqa: E402
                                 grid_frame, md2_bytes, write_aff, write_arm, write_obj, write_off, write_ply_ascii,
                                 write_ply_binary, write_stl_ascii, write_stl_binary)

FUZZ = settings(max_examples=40, deadline=3000, derandomize=True,
                suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])


def expect_error(path, *words, target=None):
    with pytest.raises(SceneFileError) as info:
        make_scene(path)
    err = info.value
    assert err.path == str(target or path), (err.path, str(target or path))
    assert str(err).startswith(err.path)
    for w in words:
        assert w.lower() in err.problem.lower(), err.problem
    return err


# ----------------------------------------------------------------------------- glTF


def gltf_tree(tmp_path, name="g.gltf"):
    p = write_arm(tmp_path / name, "u8")
    return p, json.loads(p.read_text())


def rewrite(p, tree):
    p.write_text(json.dumps(tree))
    return p


def test_gltf_truncated_glb(tmp_path):
    p = write_arm(tmp_path / "arm.glb", "u8")
    raw = p.read_bytes()
    for n in (4, 19, 40, len(raw) // 2, len(raw) - 1):
        p.write_bytes(raw[:n])
        expect_error(p, "truncat" if n >= 20 else "")
    p.write_bytes(b"")
    expect_error(p, "empty")
    p.write_bytes(b"GLTF" + raw[4:])
    expect_error(p, "header")


@pytest.mark.parametrize("edit,words", [
    (lambda t: t["meshes"][0]["primitives"][0]["attributes"].update(POSITION=99), ["accessors[99]"]),
    (lambda t: t["accessors"][0].update(count=10_000), ["need 120000 bytes"]),
    (lambda t: t["accessors"][0].update(componentType=1234), ["componentType"]),
    (lambda t: t["bufferViews"][0].update(byteOffset=10**6), ["runs past"]),
    (lambda t: t["buffers"][0].update(uri="nothere.bin"), ["missing file"]),
    (lambda t: t["buffers"][0].update(uri="data:application/octet-stream;base64,@@@"), ["base64"]),
    (lambda t: t["buffers"][0].update(byteLength=10**7), ["truncated"]),
    (lambda t: t["nodes"][1].update(children=[0]), ["cycle"]),
    (lambda t: t["nodes"][3].update(children=[4]), ["more than one parent"]),
    (lambda t: t["nodes"][0].update(children=[1, 4, 77]), ["child"]),
    (lambda t: t["animations"][0]["samplers"][0].update(interpolation="QUADRATIC"), ["interpolation"]),
    (lambda t: t["animations"][0]["samplers"][0].update(output=t["animations"][0]["samplers"][1]["output"]),
     ["output values"]),
    (lambda t: t["animations"][0]["channels"][0].update(sampler=9), ["sampler"]),
    (lambda t: t["animations"][0]["channels"][0]["target"].update(node=50), ["targets node"]),
    (lambda t: t["nodes"][0].update(matrix=[1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1]), ["matrix"]),
    (lambda t: t["skins"][0].update(joints=[0]), ["joint index"]),
    (lambda t: t["skins"][0].update(joints=[0, 60]), ["joint node"]),
    (lambda t: t["nodes"][2].update(skin=3), ["skin"]),
    (lambda t: t["meshes"][0]["primitives"][0].update(mode=9), ["mode"]),
    (lambda t: t.update(meshes=[]), ["meshes"]),
    (lambda t: t.update(extensionsRequired=["EXT_meshopt_compression"]), ["meshopt"]),
    (lambda t: t.update(asset={"version": "1.0"}), ["version"]),
    (lambda t: t.update(nodes=[{"name": "empty"}], scenes=[{"nodes": [0]}], animations=[], skins=[]),
     ["no triangles"]),
], ids=lambda v: v if isinstance(v, str) else None)
def test_gltf_malformed(tmp_path, edit, words):
    p, tree = gltf_tree(tmp_path)
    edit(tree)
    expect_error(rewrite(p, tree), *words)


def test_gltf_bad_values(tmp_path):
    p, tree = gltf_tree(tmp_path)
    bin_path = tmp_path / tree["buffers"][0]["uri"]
    blob = bytearray(bin_path.read_bytes())
    times = tree["animations"][0]["samplers"][0]["input"]
    view = tree["bufferViews"][tree["accessors"][times]["bufferView"]]
    struct.pack_into("<2f", blob, view.get("byteOffset", 0), 2.0, 1.0)  # decreasing key times
    bin_path.write_bytes(bytes(blob))
    expect_error(p, "decrease")
    struct.pack_into("<2f", blob, view.get("byteOffset", 0), 0.0, float("nan"))
    bin_path.write_bytes(bytes(blob))
    expect_error(p, "nan")
    p.write_text("{not json")
    expect_error(p, "json")
    p.write_text("[1, 2]")
    expect_error(p, "object")


# ----------------------------------------------------------------------------- BART


@pytest.mark.parametrize("root,part,words,in_part", [
    (AFF_OK.replace("part.aff", "gone.aff"), PART, ["'gone.aff' not found", "line 11"], False),
    (AFF_OK + "zz 1 2 3\n", PART, ["unknown AFF command 'zz'", "line 21"], False),
    (AFF_OK + "}\n", PART, ["without a matching"], False),
    (AFF_OK + "xs 1 1 1 0 0 1 0 0 0 0 {\n", PART, ["not closed"], False),
    (AFF_OK, PART.replace("0 2 3", "0 2 7"), ["out of range", "line 2"], True),
    (AFF_OK, PART.replace("1 1 0", "1 one 0"), ["expected a number", "not quoted"], True),  # an included file
    (AFF_OK + "l 1 one 0\n", PART, ["expected a number", "'one'", "line 21"], False),  # the root file is quoted
    (AFF_OK, PART[:40], ["unexpected end of file"], True),
    (AFF_OK, PART.replace("0 0 1  1 0 1", "0 0 nan  1 0 1"), ["non-finite"], True),
    (AFF_OK.replace("rot 4", "rot 3"), PART, ["at least 4 keys"], False),
    (AFF_OK.replace("3 0 1 0 270", "0 0 1 0 270"), PART, ["same time"], False),
    (AFF_OK.replace("0 0 1 0 0  0 0 0\n   2", "0 0 0 0 90  0 0 0\n   2"), PART, ["zero axis"], False),
    (AFF_OK.replace("rot 4", "spin 4"), PART, ["unknown keyframe type"], False),
    (AFF_OK, "i 0 part.aff\n", ["cycle"], True),
    (AFF_OK.replace("a 0 2 21", "a 2 0 21"), PART, ["end > start"], False),
    (AFF_OK, "   \n% only a comment\n", ["no triangles"], False),
])
def test_aff_malformed(tmp_path, root, part, words, in_part):
    p = write_aff(tmp_path, root, part)
    target = tmp_path / "part.aff" if in_part else p
    if words == ["no triangles"]:
        (tmp_path / "scene.aff").write_text("v\nfrom 0 0 5\nat 0 0 0\nup 0 1 0\nangle 45\nhither 1\nresolution 4 4\n")
    expect_error(p, *words, target=target)


def test_aff_empty_and_missing(tmp_path):
    p = tmp_path / "empty.aff"
    p.write_text("")
    expect_error(p, "empty")
    with pytest.raises(SceneFileError, match="not found"):
        make_scene(tmp_path / "nope.aff")


# ----------------------------------------------------------------------------- MD2


@pytest.mark.parametrize("edit,words", [
    (lambda b: b.__setitem__(slice(0, 4), b"IDP3"), ["magic"]),
    (lambda b: struct.pack_into("<i", b, 4, 7), ["version"]),
    (lambda b: struct.pack_into("<i", b, 24, 0), ["0 vertices"]),
    (lambda b: struct.pack_into("<i", b, 40, 10**6), ["frames"]),
    (lambda b: struct.pack_into("<i", b, 16, 12), ["frame size"]),
    (lambda b: struct.pack_into("<i", b, 52, 10**6), ["triangles block"]),
    (lambda b: struct.pack_into("<H", b, 68, 40), ["vertex index 40"]),
    (lambda b: struct.pack_into("<f", b, 68 + 36, float("inf")), ["non-finite"]),
    (lambda b: b.__delitem__(slice(len(b) - 10, len(b))), ["truncated"]),
    (lambda b: b.__delitem__(slice(30, len(b))), ["truncated"]),
], ids=["magic", "version", "no-vertices", "frames", "framesize", "tris-offset", "index", "inf", "tail", "header"])
def test_md2_malformed(tmp_path, edit, words):
    p, raw = md2_bytes(tmp_path)
    edit(raw)
    p.write_bytes(bytes(raw))
    expect_error(p, *words)


# ----------------------------------------------------------------------------- hypothesis: truncation and mutation


def seed_files(tmp):
    """name -> (path to load, list of files to mutate)."""
    out = {}
    glb = write_arm(tmp / "arm.glb", "u8")
    out["glb"] = (glb, [glb])
    b = Builder()
    m = b.mesh(TRI_V, TRI_F, targets=[TRI_V * 0.5], weights=[0.0])
    b.node(root=True, mesh=m)
    b.animation("m", [(0, "weights", [0.0, 1.0], [0.0, 1.0], "LINEAR")])
    gltf = b.save(tmp / "morph.gltf")
    out["gltf-json"] = (gltf, [gltf])
    out["gltf-bin"] = (gltf, [tmp / "morph.bin"])
    aff_dir = tmp / "aff"
    aff_dir.mkdir()
    aff = write_aff(aff_dir)
    out["aff"] = (aff, [aff])
    out["aff-include"] = (aff, [aff_dir / "part.aff"])
    md2, _ = md2_bytes(tmp)
    out["md2"] = (md2, [md2])
    frames = tmp / "frames"
    frames.mkdir()
    for k in range(3):
        write_obj(frames / f"f{k:03d}.obj", grid_frame(k), GRID_F)
    out["frames"] = (frames, [frames / "f001.obj"])
    static = tmp / "static"
    static.mkdir()
    for name, write in (("obj", lambda q: write_obj(q, OCTA_V, OCTA_F)), ("off", lambda q: write_off(q, OCTA_V, OCTA_F)),
                        ("ply", lambda q: write_ply_ascii(q, OCTA_V, OCTA_F)),
                        ("PLY", lambda q: write_ply_binary(q, OCTA_V, OCTA_F)),
                        ("stl", lambda q: write_stl_ascii(q, OCTA_T)), ("STL", lambda q: write_stl_binary(q, OCTA_T))):
        q = static / f"octa_{name}.{name}"
        write(q)
        out[f"{name}-{'binary' if name.isupper() else 'text'}"] = (q, [q])
    return out


@pytest.fixture(scope="module")
def seeds(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("fuzz")
    files = seed_files(tmp)
    for path, _ in files.values():  # compile the kernels before any timed example
        make_scene(path).triangles_at(0.1)
    return files


def check_outcome(path, targets):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            s = make_scene(path)
            tris = s.triangles_at(0.37)
            assert np.isfinite(tris).all()
        except SceneFileError as e:
            allowed = {str(path)} | {str(t) for t in targets}
            if path.is_dir():
                allowed |= {str(q) for q in path.iterdir()}
            assert e.path in allowed, (e.path, allowed)
            assert e.problem
    numpy_warnings = [f"{w.category.__name__}: {w.message} ({w.filename}:{w.lineno})" for w in caught
                      if issubclass(w.category, RuntimeWarning)]
    assert not numpy_warnings, numpy_warnings


NUMBER = re.compile(rb"-?\d+(\.\d*)?([eE][-+]?\d+)?")
EXTREMES = [b"1e300", b"-1e300", b"1e39", b"3.4e38", b"nan", b"inf", b"-1", b"0", b"1e-320", b"4294967296"]


@pytest.mark.parametrize("name", ["glb", "gltf-json", "gltf-bin", "aff", "aff-include", "md2", "frames", "obj-text",
                                  "off-text", "ply-text", "PLY-binary", "stl-text", "STL-binary"])
@FUZZ
@given(data=st.data())
def test_truncated_or_mutated_files(seeds, name, data):
    path, targets = seeds[name]
    originals = {t: t.read_bytes() for t in targets}
    try:
        for t, raw in originals.items():
            mode = data.draw(st.sampled_from(["truncate", "flip", "splice", "numbers"]), label="mode")
            if mode == "numbers":  # numeric tokens of a text file (or digits in a binary one) made extreme
                spans = [m.span() for m in NUMBER.finditer(raw)]
                new = raw
                for a, b in sorted(data.draw(st.lists(st.sampled_from(spans), min_size=1, max_size=4, unique=True),
                                             label="tokens") if spans else [], reverse=True):
                    new = new[:a] + data.draw(st.sampled_from(EXTREMES), label="value") + new[b:]
            elif mode == "truncate":
                cut = data.draw(st.integers(0, max(len(raw) - 1, 0)), label="cut")
                new = raw[:cut]
            elif mode == "flip":
                buf = bytearray(raw)
                for _ in range(data.draw(st.integers(1, 6), label="flips")):
                    i = data.draw(st.integers(0, len(buf) - 1), label="at")
                    buf[i] = data.draw(st.integers(0, 255), label="byte")
                new = bytes(buf)
            else:
                i = data.draw(st.integers(0, len(raw)), label="at")
                junk = data.draw(st.binary(max_size=12) | st.sampled_from(
                    [b"}", b"{", b" 1e300", b" -1", b" nan", b"999999999", b'"', b"[", b"null"]), label="junk")
                new = raw[:i] + junk + raw[i:]
            t.write_bytes(new)
        check_outcome(path, targets)
    finally:
        for t, raw in originals.items():
            t.write_bytes(raw)
