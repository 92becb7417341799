"""One installed package named gridrt: a wheel built from the repository holds no other top-level
name, carries its shaders, and runs from its own files (``import gridrt``, ``python -m gridrt``)."""

import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


#: what pyproject packages (copied into a clean folder to build: setuptools would otherwise add
#: whatever an earlier build left in the repository's build/lib to the wheel)
SOURCES = ("pyproject.toml", "README.md", "engine", "app", "shaders", "assets")


@pytest.fixture(scope="module")
def wheel(tmp_path_factory):
    src, out = tmp_path_factory.mktemp("src"), tmp_path_factory.mktemp("wheel")
    for name in SOURCES:
        if (REPO / name).is_dir():
            shutil.copytree(REPO / name, src / name, ignore=shutil.ignore_patterns("__pycache__"))
        else:
            shutil.copyfile(REPO / name, src / name)
    r = subprocess.run([sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "-w", str(out), str(src)],
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    (whl,) = out.glob("gridrt-*.whl")
    return whl


@pytest.mark.slow  # (builds and installs a wheel in a venv of its own)
def test_wheel_installs_only_gridrt(wheel):
    names = zipfile.ZipFile(wheel).namelist()
    top = {n.split("/")[0] for n in names}
    assert {t for t in top if not t.endswith(".dist-info")} == {"gridrt"}, sorted(top)
    for want in ("gridrt/__init__.py", "gridrt/__main__.py", "gridrt/app/__main__.py", "gridrt/grid/build.py",
                 "gridrt/trace/cgt/walk.py", "gridrt/scene/gltf.py", "gridrt/shaders/blit.vert",
                 "gridrt/shaders/blit.frag"):
        assert want in names, want
    entry = [n for n in names if n.endswith("entry_points.txt")]
    assert entry and "gridrt = gridrt.app.__main__:main" in zipfile.ZipFile(wheel).read(entry[0]).decode()
    assets = [p for p in (REPO / "assets").rglob("*") if p.is_file() and not p.name.startswith(".")]
    assert any(p.name == "README.md" for p in assets) and len(assets) > 1
    for p in assets:  # every shipped asset (and its README: origins, licences) byte for byte
        name = "gridrt/assets/" + p.relative_to(REPO / "assets").as_posix()
        assert name in names and zipfile.ZipFile(wheel).read(name) == p.read_bytes(), name


@pytest.mark.slow  # (builds and installs a wheel in a venv of its own)
def test_wheel_runs_from_its_own_files(wheel, tmp_path):
    """Unpacked alone on the path (no repository): the package, its shaders, its assets (the
    built-in scenes load from gridrt/assets) and -m gridrt."""
    site = tmp_path / "site"
    zipfile.ZipFile(wheel).extractall(site)
    env = dict(os.environ, PYTHONPATH=str(site))
    code = ("import gridrt, gridrt.app.viewer.blit as b; print(gridrt.__file__); print(b.SHADER_DIR); "
            "print(gridrt.RayCaster.__module__)")
    r = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, env=env, capture_output=True, text=True,
                       timeout=300)
    assert r.returncode == 0, r.stderr
    init, shaders, module = r.stdout.split()
    assert Path(init).is_relative_to(site) and Path(shaders).is_relative_to(site) and module == "gridrt.api"
    assert (Path(shaders) / "blit.vert").is_file()
    r = subprocess.run([sys.executable, "-m", "gridrt", "strategies"], cwd=tmp_path, env=env, capture_output=True,
                       text=True, timeout=300)
    assert r.returncode == 0 and "serial" in r.stdout, r.stderr
    from gridrt.scene import make_scene

    code = ("import gridrt.scene as s; print(s.ASSET_DIR); "
            "print(*(s.make_scene(n).triangles_at(0.0).shape[0] for n in ('morph_sphere', 'museum')))")
    r = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, env=env, capture_output=True, text=True,
                       timeout=300)
    assert r.returncode == 0, r.stderr
    where, *counts = r.stdout.split()
    assert Path(where) == site / "gridrt" / "assets"
    assert [int(c) for c in counts] == [make_scene(n).triangles_at(0.0).shape[0] for n in ("morph_sphere", "museum")]


def test_numba_imported_before_gridrt():
    """A program that imports numba before gridrt keeps numba's thread count: gridrt casts with it,
    and the program's own kernels still compile after gridrt's threads run (a changed
    NUMBA_NUM_THREADS would stop that compile with a RuntimeError)."""
    code = (
        "import numba, numpy as np\n"
        "import gridrt\n"
        "from gridrt import RayCaster\n"
        "from gridrt.scene import icosphere_mesh\n"
        "from gridrt.threads import max_threads\n"
        "m = icosphere_mesh(320)\n"
        "rc = RayCaster(m.vertices, m.faces)\n"
        "o, d = np.zeros((20000, 3)), np.random.default_rng(1).normal(size=(20000, 3))\n"
        "hit = rc.cast(o, d)\n"
        "assert np.isfinite(hit.t).all()\n"
        "own = numba.njit(lambda x: x + 1)\n"
        "assert own(1) == 2\n"
        "print(max_threads(), numba.config.NUMBA_NUM_THREADS)\n")
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_NUM_THREADS"}
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=600, cwd=REPO, env=env)
    assert r.returncode == 0, r.stderr[-3000:]
    have, numba_default = (int(x) for x in r.stdout.split())
    assert have == numba_default == (os.cpu_count() or 1)
