"""The real files in assets/ and the built-in scenes made of them.

* assets/README.md lists every shipped file with its SHA-256 (checked here against the bytes),
  and each built-in asset scene with the triangle count it documents; the folder stays small.
* Each asset scene loads with the documented count and the same triangles as an independent
  reader of its file (trimesh for meshes, pygltflib index counts for glTF, the MD2 header);
  the Armadillo is closed and the teapot is not (as documented); the animated ones move and the
  static ones do not.
* Through the real command line: ``--help`` and the unknown-scene error list the names, a count
  for a fixed asset is refused in one line, and ``gridrt dump --scene morph_sphere`` renders
  two different frames that match the brute-force caster.
"""

import csv
import hashlib
import re
import struct

import numpy as np
import pytest

from conftest import ASSETS, CONVERTED, NO_SHARED_DATA, SHARED_DATA, SHIPPED
from gridrt.errors import InputError, SceneFileError
from gridrt.scene import ASSET_DIR, ASSET_SCENES, BUILTIN_SCENES, make_scene
from reference import compare_hits, ref_camera_rays, ref_cast
from helpers.cli import gridrt, one_error

README = ASSETS / "README.md"
ANIMATED = ("cesium_man", "morph_sphere", "sydney", "museum")
STATIC = ("armadillo", "teapot")


def readme_checksums():
    block = re.search(r"## SHA-256\s+```\n(.*?)```", README.read_text(), re.S).group(1)
    return {name: digest for digest, name in (ln.split() for ln in block.strip().splitlines())}


def readme_rows():
    """scene name -> (files cell, triangles) of the README's table."""
    rows = {}
    for ln in README.read_text().splitlines():
        m = re.match(r"\| `(\w+)` \| (.*?) \| .*? \| ([\d,]+)", ln)
        if m:
            rows[m.group(1)] = (m.group(2), int(m.group(3).replace(",", "")))
    return rows


def test_readme_checksums_match_every_shipped_file():
    sums = readme_checksums()
    files = {p.relative_to(ASSETS).as_posix() for p in ASSETS.rglob("*")
             if p.is_file() and p.name != "README.md" and not p.name.startswith(".")}  # not .gitattributes
    assert set(sums) == files
    for name, digest in sums.items():
        assert hashlib.sha256((ASSETS / name).read_bytes()).hexdigest() == digest, name
    total = sum((ASSETS / n).stat().st_size for n in files)
    # a few MB: the meshes (4 MB) and the museum's five textures (3.8 MB of PPM, so that the shipped
    # BART scene looks like itself in a clone without the data set)
    assert total < 8_500_000, f"assets/ holds {total:,} bytes: at most a few MB"


def test_shipped_copies_are_the_shared_data_files():
    """conftest maps the development data set's names onto assets/: the same bytes, or (armadillo) the same mesh."""
    if NO_SHARED_DATA or not SHARED_DATA.is_dir():
        pytest.skip(f"{SHARED_DATA} is absent (or ignored: GRIDRT_NO_SHARED_DATA): nothing to compare the copies with")
    import trimesh

    for rel, name in SHIPPED.items():
        if (SHARED_DATA / rel).is_file():
            assert (ASSETS / name).read_bytes() == (SHARED_DATA / rel).read_bytes(), name
    for rel, name in CONVERTED.items():
        a = trimesh.load(SHARED_DATA / rel, force="mesh", process=False)
        b = trimesh.load(ASSETS / name, force="mesh", process=False)
        assert np.array_equal(np.asarray(a.vertices, np.float32), np.asarray(b.vertices, np.float32))
        assert np.array_equal(a.faces, b.faces)


def test_every_asset_scene_is_a_builtin_with_a_readme_row():
    rows = readme_rows()
    assert set(ASSET_SCENES) == set(rows) and set(ASSET_SCENES) <= set(BUILTIN_SCENES)
    assert ASSET_DIR == ASSETS  # the source checkout's folder (a wheel's is checked in test_package)
    for name, (rel, _) in ASSET_SCENES.items():
        assert f"`{rel}`" in rows[name][0], (name, rel)


def independent_count(path):
    """Triangle count of a file by a reader that is not gridrt's."""
    if path.suffix in (".obj", ".ply", ".off"):
        import trimesh

        return len(trimesh.load(path, force="mesh", process=False).faces)
    if path.suffix in (".glb", ".gltf"):
        import pygltflib

        g = pygltflib.GLTF2().load(str(path))
        return sum(g.accessors[p.indices].count // 3 for m in g.meshes for p in m.primitives)
    if path.suffix == ".md2":
        # MD2 header: ident, version, skin width and height, frame size, num_skins, num_xyz, num_st, num_tris
        return struct.unpack_from("<17i", path.read_bytes())[8]
    return None


@pytest.mark.parametrize("name", list(ASSET_SCENES))
def test_asset_scene_loads_with_the_documented_count(name):
    scene = make_scene(name)
    n = readme_rows()[name][1]
    tris = scene.triangles_at(0.0)
    assert tris.shape == (n, 3, 3) and tris.dtype == np.float32 and np.isfinite(tris).all()
    path = ASSETS / ASSET_SCENES[name][0]
    if (k := independent_count(path)) is not None:
        assert k == n
    assert make_scene(f" {name.upper()} ").triangles_at(0.0).shape == tris.shape  # names as the built-ins


@pytest.mark.parametrize("name", STATIC)
def test_static_assets_are_the_files_triangles(name):
    import trimesh

    m = trimesh.load(ASSETS / ASSET_SCENES[name][0], force="mesh", process=False)
    want = np.asarray(m.vertices, np.float32)[m.faces]
    scene = make_scene(name)
    assert scene.static
    np.testing.assert_array_equal(scene.triangles_at(0.0), want)
    np.testing.assert_array_equal(scene.triangles_at(3.7), want)


def boundary_edges(faces):
    e = np.sort(np.asarray(faces)[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    _, counts = np.unique(e, axis=0, return_counts=True)
    return int((counts != 2).sum())


def test_armadillo_is_closed_and_the_teapot_is_not():
    from gridrt.scene import load_mesh

    assert boundary_edges(load_mesh(ASSETS / "armadillo.ply").faces) == 0
    assert boundary_edges(load_mesh(ASSETS / "teapot.obj").faces) > 0


@pytest.mark.parametrize("name", ANIMATED)
def test_animated_assets_move(name):
    scene = make_scene(name)
    assert not scene.static and scene.duration > 0
    a = scene.triangles_at(0.0).copy()
    b = scene.triangles_at(scene.duration * 0.37).copy()
    assert a.shape == b.shape
    moved = np.abs(a - b).max(axis=(1, 2))
    assert moved.max() > 1e-3 * np.ptp(a.reshape(-1, 3), axis=0).max(), name


def test_asset_scene_options():
    with pytest.raises(InputError, match="count applies to the marbles and icosphere"):
        make_scene("armadillo", count=1000)
    assert make_scene("teapot", subdivide=20_000).triangles_at(0.0).shape[0] == 6320 * 4
    with pytest.raises(InputError, match="animated already"):
        make_scene("cesium_man", animate="twist")
    twisted = make_scene("teapot", animate="twist")
    assert not np.array_equal(twisted.triangles_at(0.0).copy(), twisted.triangles_at(0.3))


def test_missing_asset_file_names_it(monkeypatch, tmp_path):
    import gridrt.scene.assets as assets

    monkeypatch.setattr(assets, "ASSET_DIR", tmp_path)
    with pytest.raises(SceneFileError, match="teapot") as e:
        make_scene("teapot")
    assert e.value.path == str(tmp_path / "teapot.obj")


# ------------------------------------------------------------------------- the command line


def test_help_and_unknown_scene_list_the_builtin_names(tmp_path):
    r = gridrt("dump", "--help")
    assert r.returncode == 0, r.stderr
    text = " ".join(r.stdout.split())
    for name in BUILTIN_SCENES:
        assert name in text, name
    line = one_error(gridrt("dump", "--scene", "no_such_scene", "--frames", "1", "--out", str(tmp_path)),
                     "no_such_scene")
    for name in BUILTIN_SCENES:
        assert name in line, name
    one_error(gridrt("dump", "--scene", "armadillo", "--count", "100", "--frames", "1", "--out", str(tmp_path)),
              "count", "armadillo")


def test_dump_morph_sphere_renders_two_different_frames(tmp_path):
    out = tmp_path / "d"
    W, H, t0, dt = 40, 30, 0.5, 2.0
    scene = make_scene(str(ASSETS / "AnimatedMorphSphere.gltf"))
    p = scene.triangles_at(t0).reshape(-1, 3)
    c = (p.min(axis=0) + p.max(axis=0)) / 2
    r = float(np.ptp(p, axis=0).max())
    eye, target, up, fov = tuple(c + np.array([0.3, 0.4, 2.2]) * r), tuple(c), (0.0, 1.0, 0.0), 45.0
    res = gridrt("dump", "--scene", "morph_sphere", "--frames", "2", "--t0", str(t0), "--dt", str(dt),
                 "--size", f"{W}x{H}", "--eye", ",".join(map(str, eye)), "--target", ",".join(map(str, target)),
                 "--up", "0,1,0", "--fov", str(fov), "--save-buffers", "--no-progress", "--out", str(out))
    assert res.returncode == 0, res.stderr
    with open(out / "stats.csv") as fh:
        rows = list(csv.DictReader(fh))
    assert [int(row["triangles"]) for row in rows] == [readme_rows()["morph_sphere"][1]] * 2
    o, d = ref_camera_rays(eye, target, up, fov, W, H)
    ts = []
    for i in range(2):
        tb = np.load(out / f"frame_{i:05d}_t.npy")
        ib = np.load(out / f"frame_{i:05d}_id.npy")
        ref = ref_cast(scene.triangles_at(t0 + i * dt).copy(), o, d)
        diff = compare_hits(tb.reshape(-1), ib.reshape(-1), ref, t_rtol=1e-6)
        assert len(diff.bad) == 0, f"frame {i}: {len(diff.bad)} pixels differ from brute force"
        assert (ib >= 0).any() and (ib < 0).any(), "the camera should see the sphere and the background"
        ts.append(tb)
    both = np.isfinite(ts[0]) & np.isfinite(ts[1])
    assert np.abs(ts[0][both] - ts[1][both]).max() > 1e-3 * r, "the sphere did not morph between the frames"


def test_static_assets_list_is_what_loads_static():
    """STATIC_ASSETS (the viewer offers a deformation for these) is exactly the set of asset scenes
    that load as static meshes, and a deformation animates each of them."""
    from gridrt.scene.assets import STATIC_ASSETS

    assert set(STATIC_ASSETS) == {n for n in ASSET_SCENES if make_scene(n).static}
    for n in STATIC_ASSETS:
        assert not make_scene(n, animate="twist").static
