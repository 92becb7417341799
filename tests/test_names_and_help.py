"""One name for each scene, one help text for each shared option, and benchmark plots legible at
their saved size.

* Scene names: every name of ``gridrt.scene.BUILTIN_SCENES`` (the one list ``--help`` and the
  documents give) means the same file through ``--scene`` (the command line's SceneSpec, made)
  and through a benchmark's scene spec (``parse_scene_spec``); the development data set's names
  are skipped, with the reason, where it is absent.  The older spellings ``cesium`` and
  ``morphsphere`` still work in scene specs and appear in no help text; an unknown name, and a data
  set scene without the data set, are one clear error, the same in both places.
* Shared options: each option of ``gridrt.app.cli.OPTION_HELP`` shows that text in every parser
  that has it (``gridrt dump|view|bench X``), a command's own default and a benchmark's "several,
  comma-separated" note aside; an option that several commands have with other texts is listed
  here with the reason.
* Plots: each benchmark's plot, drawn from small synthetic rows as its benchmark writes them, is
  saved; no legend overlaps the data area of any axes, every text drawn lies inside the saved
  image, is MIN_FONT points or more at MIN_DPI or more, and x tick labels stand apart.
"""

import argparse
import re
from collections import defaultdict
from pathlib import Path

import pytest

from gridrt.app import cli
from gridrt.app.__main__ import build_parser, main
from gridrt.app.bench import build, core, frame, native, output, peers, trade
from gridrt.app.bench.scenes import ALIASES, parse_scene_spec, resolve_scene, scene_spec
from gridrt.config import STRATEGIES
from gridrt.errors import InputError
from gridrt.scene import BUILTIN_SCENES, DATA_SCENES, SceneSpec, make_scene, scene_choices
from gridrt.scene import assets
from gridrt.scene import make as scene_make
from gridrt.scene.assets import scene_file, scene_present
from gridrt.scene.make import PROCEDURAL_SCENES
from helpers.cli import all_parsers


# ----------------------------------------------------------------------------- scene names


@pytest.fixture
def file_of(monkeypatch):
    """make_scene returning the file (or folder) it would load instead of loading it."""
    monkeypatch.setattr(scene_make, "_file_scene", lambda path, *args: Path(path))
    return make_scene


def cli_scene(name):
    a = build_parser("dump").parse_args(["dump", "--scene", name])
    return cli.scene_spec(a)


@pytest.mark.parametrize("name", list(BUILTIN_SCENES))
def test_every_scene_name_means_one_file_in_scene_and_bench_specs(name, file_of):
    if name in DATA_SCENES and not scene_present(name):
        why = "GRIDRT_NO_SHARED_DATA hides it" if assets.DATA_HIDDEN else "the data set is not part of the repository"
        pytest.skip(f"{scene_file(name)}, of the development data set, is absent ({why})")
    src, kw = parse_scene_spec(name)
    assert kw == {}
    if name in PROCEDURAL_SCENES:
        assert src == name == cli_scene(name).source
        return
    path = scene_file(name)
    assert path.exists()
    assert Path(src) == path, "the benchmarks' spec names another file"
    assert cli_scene(name).make() == path, "--scene loads another file"
    assert scene_spec(name).make() == path
    assert make_scene(name.upper()) == path  # (names are not case-sensitive)


def test_a_name_that_ships_means_the_shipped_file_with_or_without_the_data_set(file_of, monkeypatch, tmp_path):
    """armadillo, teapot, museum (and the other shipped scenes) are assets/ files whether or not the
    development data set (which holds copies of them) is there; a data set scene is its file there."""
    for present in (True, False):
        if not present:
            monkeypatch.setattr(assets, "DATA_DIR", tmp_path)
        for name in assets.ASSET_SCENES:
            assert Path(parse_scene_spec(name)[0]) == assets.asset_path(name) == make_scene(name)
    assert set(assets.ASSET_SCENES).isdisjoint(DATA_SCENES)
    assert all(scene_file(n) == tmp_path / rel for n, (rel, _) in DATA_SCENES.items())


def test_older_spellings_still_work_in_bench_specs_and_no_help_names_them():
    assert ALIASES == {"cesium": "cesium_man", "morphsphere": "morph_sphere"}
    for old, name in ALIASES.items():
        assert parse_scene_spec(old) == parse_scene_spec(name)
        assert parse_scene_spec(f" {old.title()}:twist ") == parse_scene_spec(f"{name}:twist")
    shown = [scene_choices()]
    for _, p in all_parsers():
        shown += [a.help for a in p._actions if {"--scene", "--scenes"} & set(a.option_strings)]
    assert len(shown) > 8
    for text in shown:
        for old in ALIASES:
            assert not re.search(rf"\b{old}\b", text), text
    for text in shown[:3]:  # --scene of view and dump: every name
        assert all(re.search(rf"\b{n}\b", text) for n in BUILTIN_SCENES), text


def one_line_error(capsys, argv):
    assert main(argv) == 2
    lines = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("gridrt: error: "), lines
    return lines[0].removeprefix("gridrt: error: ")


def test_an_unknown_name_is_one_clear_error_the_same_everywhere(capsys, tmp_path):
    with pytest.raises(InputError) as scene:
        SceneSpec(source="no_such_scene").make()
    with pytest.raises(InputError) as bench:
        resolve_scene("no_such_scene")
    said = str(scene.value)
    assert said == str(bench.value) and "\n" not in said
    assert said.startswith("unknown scene 'no_such_scene'") and all(n in said for n in BUILTIN_SCENES)
    assert one_line_error(capsys, ["dump", "--scene", "no_such_scene", "--out", str(tmp_path / "d")]) == said
    assert one_line_error(capsys, ["bench", "frame", "--scenes", "no_such_scene", "--quick", "--no-progress",
                                   "--out", str(tmp_path / "b")]) == said


def test_a_data_set_scene_without_the_data_set_is_one_error_naming_its_file(monkeypatch, tmp_path, capsys):
    monkeypatch.setattr(assets, "DATA_DIR", tmp_path)
    for name, (rel, _) in DATA_SCENES.items():
        with pytest.raises(InputError) as scene:
            SceneSpec(source=name).make()
        with pytest.raises(InputError) as bench:
            parse_scene_spec(f"{name}:twist")
        said = str(scene.value)
        assert said == str(bench.value) and "\n" not in said
        assert str(tmp_path / rel) in said and all(n in said for n in ("marbles", *assets.ASSET_SCENES))
        assert one_line_error(capsys, ["dump", "--scene", name, "--out", str(tmp_path / "d")]) == said


# ----------------------------------------------------------------------------- shared options' help


#: options several commands have, each with its own text, and why
OWN_TEXTS = {
    "--scene": "a benchmark's --scene is a scene spec NAME[:N][:twist|wave] (names: the tests above)",
    "--size": "an image WIDTHxHEIGHT in view and dump, a square image's edge in the benchmarks",
    "--seed": "the procedural scenes' seed in view and dump, the pixel sample's in bench trade",
    "--frames": "the dump's frames, and in bench cluster the frames of each dump it runs",
    "--out": "the dump's folder (refused when it holds another dump), or a benchmark's",
    "--no-progress": "the dump's one progress bar, a benchmark's several",
    "--workers": "what a cluster spreads is each command's own (gridrt.app.cluster.scheduler.add_cluster_args)",
    "--scheduler": "what a cluster spreads is each command's own (gridrt.app.cluster.scheduler.add_cluster_args)",
    "--views": "bench peers and bench packets look at different ray sets",
    "--dump-args": "bench start adds them to one dump, bench cluster to every dump",
}


def without_default(text):
    """A help text less the default a command says after it (" (default...)" at its end)."""
    cut = text.rfind(" (default")
    return text[:cut] if cut >= 0 and text.endswith(")") else text


def test_each_shared_option_has_one_help_text_wherever_it_appears():
    uses = defaultdict(list)
    for name, p in all_parsers():
        for a in p._actions:
            if a.option_strings and not isinstance(a, argparse._HelpAction):
                uses[a.option_strings[0]].append((name, a.help))
    assert set(cli.OPTION_HELP) <= set(uses)
    for option, text in cli.OPTION_HELP.items():
        assert len(uses[option]) >= 2, option
        for name, help_text in uses[option]:
            assert without_default(help_text).removesuffix(cli.SEVERAL) == text, (name, option, help_text)
        by_command = dict(uses[option])
        if "gridrt view" in by_command:  # the same option of view and dump: the same text, default and all
            assert by_command["gridrt view"] == by_command["gridrt dump"], option
    assert len(uses["--shadows"]) == 2 and uses["--shadows"][0][1] == cli.OPTION_HELP["--shadows"]
    for option, where in uses.items():
        if len(where) > 1 and option not in cli.OPTION_HELP:
            texts = {without_default(t) for _, t in where}
            assert len(texts) == 1 or option in OWN_TEXTS, (option, where)


def test_help_of_several_values_appears_where_a_benchmark_takes_a_list():
    a = build_parser().parse_args(["bench", "frame", "--threads", "1,2", "--traversal", "cgt,dda", "--grid",
                                   "uniform,two_level"])
    assert (a.threads, a.traversal, a.grid) == ("1,2", "cgt,dda", "uniform,two_level")
    bench = dict(all_parsers())["gridrt bench frame"]
    for action in bench._actions:
        if {"--threads", "--traversal", "--grid"} & set(action.option_strings):
            assert cli.SEVERAL in action.help, action.help


# ----------------------------------------------------------------------------- plots


def _timed(ms, spread=0.1):
    return {"": ms, "_min": ms * (1 - spread), "_max": ms * (1 + spread)}


SCENES = ["marbles", "cesium_man", "lucy:1600000:twist", "kitchen", "icosphere:1310720:twist",
          "armadillo:twist", "robots", "museum"]


def core_rows():
    rows = []
    for k, s in enumerate(SCENES[:3]):
        label = f"{s} ({['Marbles', 'CesiumMan.glb', 'Lucy100k.ply'][k]}, {10 ** (k + 4):,} triangles)"
        for ins, ms in (("bbox", 8.0 * (k + 1)), ("exact", 30.0 * (k + 1))):
            rows.append(dict(scene=label, what=f"serial build {ins}", threads=1, median_ms=ms, mrays=""))
        for th in (1, 2):
            for tv in ("dda", "cgt"):
                rows.append(dict(scene=label, what=f"{tv} rays", threads=th, traversal=tv, median_ms=50.0,
                                 mrays=5.0 * th * (4 if tv == "cgt" else 1)))
    return rows


def build_rows(scenes):
    rows = []
    for k, s in enumerate(scenes):
        for n, strategy in enumerate(STRATEGIES):
            for th in (1, 2):
                r = dict(scene=s, triangles=10 ** (k + 4), strategy=strategy, grid="uniform", threads=th)
                for key, ms in (("build_ms", 10.0 + n), ("clear_ms", 1.0 + n / 10), ("insert_ms", 8.0 + n),
                                ("macro_ms", 0.5 + n / 20)):
                    for suffix, v in _timed(ms * (1.5 if th == 1 else 1.0) * (k + 1)).items():
                        r[key + suffix] = v
                rows.append(r)
    return rows


def frame_rows():
    rows = []
    for k, s in enumerate(SCENES[:6]):
        for th in (1, 2):
            for split in (1, 0):
                rows.append(dict(scene=s, threads=th, traversal="cgt", split=split, grid="uniform",
                                 fps=30.0 / (k + 1) * th, frame_ms=33.0 * (k + 1) / th, anim_ms=1.0 + k,
                                 build_ms=5.0 * (k + 1), render_ms=27.0 * (k + 1) / th, size=1024, frames=5))
    return rows


def peers_rows():
    rows = []
    for k, s in enumerate(SCENES[:5]):  # (as many as the default run's: peers.PEER_SCENES)
        for view in ("frame", "fill", "random"):
            for th in (1, 2):
                rows.append(dict(scene=f"{s} [{view}]", threads=th, grid="uniform", o_build_ms=1.0 + k,
                                 o_cast_ms=90.0 + 10 * k, e_upload_ms=5.0, e_commit_ms=1.5 + k, e_cast_ms=50.0 + k,
                                 o_mrays=12.0 + k, o_mrays_cgt=25.0 + k, e_mrays=19.0 - k))
    return rows


def native_rows():
    rows = []
    for k, s in enumerate(SCENES[:4]):  # (as many as the default run's: native.NATIVE_SCENES)
        for th in (1, 2):
            rows.append(dict(scene=s, threads=th, o_mrays_random=1.0 + k, n_mrays_random=4.0 + k, e_mrays_random=3.0,
                             o_mrays_cgt=12.0 + k, o_mrays_camera=8.0 + k, n_mrays_camera=25.0 - k,
                             o_frame_ms=60.0 * (k + 1), n_refit_frame_ms=40.0 * (k + 1), n_rebuild_frame_ms=45.0 * (k + 1)))
    return rows


def trade_rows():
    rows = []
    values = {"insert": ["bbox", "exact"], "lambda": ["0.5", "1", "2", "4", "8", "12"], "macro": ["1", "2", "4", "8"],
              "intersect": ["watertight", "fast"], "traversal": ["dda", "cgt"],
              "resolution": ["256x256", "512x512", "1024x1024"], "packet": ["4x4", "8x8", "16x16"],
              "packet_precision": ["float64", "float32"], "grid": ["uniform", "two_level", "auto"],
              "top_density": ["0.0625", "0.125"], "leaf_density": ["1", "2"]}
    for n, (knob, vals) in enumerate(values.items()):
        for m, v in enumerate(vals):
            total = 20.0 * (1 + n) + 15.0 * m
            rows.append(dict(knob=knob, value=v, default=int(n == 0 and m == 0), pareto=int(m == 0),
                             total_ms=total, build_ms=total / 10, render_ms=total * 0.9,
                             pixel_error=0.1 / (1 + m) if knob == "resolution" else 0.0,
                             holes_per_million=1e5 if v == "fast" else 0.0))
    return rows


PLOTS = {
    "core": (core, core._plot_core, core_rows),
    "build methods, one scene": (build, build.plot_methods, lambda: build_rows(SCENES[:1])),
    "build methods": (build, build.plot_methods, lambda: build_rows(SCENES[:4])),
    "build steps": (build, build.plot_steps, lambda: build_rows(SCENES[:2])),
    "frame": (frame, frame._plot_frame, frame_rows),
    "peers": (peers, peers._plot, peers_rows),
    "native": (native, native._plot, native_rows),
    "trade": (trade, trade._plot_trade, trade_rows),
    "trade knobs": (trade, trade._plot_knobs, trade_rows),
}


@pytest.mark.slow  # (draws every plot of each benchmark and measures its lettering, up to 7 s a benchmark)
@pytest.mark.parametrize("kind", list(PLOTS))
def test_benchmark_plots_are_legible_at_their_saved_size(kind, tmp_path, monkeypatch):
    from matplotlib.backends.backend_agg import RendererAgg
    from PIL import Image

    module, plot, rows = PLOTS[kind]
    figs = []

    def figure(*args, **kw):
        fig, ax = output.figure(*args, **kw)
        figs.append(fig)
        return fig, ax

    drawn = []  # (text, its extent, the image's (width, height)) of each text the saved image draws
    draw_text = RendererAgg.draw_text

    def record(self, gc, x, y, s, prop, angle, ismath=False, mtext=None):
        if mtext is not None:
            drawn.append((mtext, mtext.get_window_extent(self), (self.width, self.height)))
        return draw_text(self, gc, x, y, s, prop, angle, ismath=ismath, mtext=mtext)

    monkeypatch.setattr(module, "figure", figure)
    monkeypatch.setattr(RendererAgg, "draw_text", record)
    path = tmp_path / "plot.png"
    plot(rows(), path)
    monkeypatch.undo()

    assert len(figs) == 1 and drawn
    fig = figs[0]
    with Image.open(path) as im:
        size, dpi = im.size, im.info.get("dpi", (0, 0))[0]
    assert dpi == pytest.approx(output.MIN_DPI, abs=1) or dpi > output.MIN_DPI
    for t, box, image in drawn:
        assert image == size
        assert -1 <= box.x0 and box.x1 <= size[0] + 1 and -1 <= box.y0 and box.y1 <= size[1] + 1, \
            f"{t.get_text()!r} at {box} is cut: the image is {size}"
        assert t.get_fontsize() >= output.MIN_FONT, (t.get_text(), t.get_fontsize())

    fig.draw_without_rendering()
    renderer = fig.canvas.get_renderer()
    axes = [ax for ax in fig.axes if ax.get_visible()]
    legends = [ax.get_legend() for ax in axes if ax.get_legend() is not None] + list(fig.legends)
    assert legends
    for leg in legends:
        lb = leg.get_window_extent(renderer)
        for ax in axes:
            assert not lb.overlaps(ax.get_window_extent(renderer)), f"a legend covers the data of {ax.get_title()!r}"
    for ax in axes:
        labels = output._tick_labels(ax)
        level = [t for t in labels if t.get_rotation() % 180 == 0]
        boxes = sorted((t.get_window_extent(renderer) for t in level), key=lambda b: b.x0)
        assert all(a.x1 <= b.x0 for a, b in zip(boxes, boxes[1:])), f"x tick labels overlap in {ax.get_title()!r}"
        assert output._crowding(ax, renderer) <= 1, f"x tick labels overlap in {ax.get_title()!r}"


def test_static_data_set_scenes_are_the_static_ones():
    """STATIC_DATA_SCENES (the viewer offers a deformation for these) are the data set's scenes that
    do not move, each one present checked by loading it."""
    from gridrt.scene import DATA_SCENES, make_scene
    from gridrt.scene.assets import STATIC_DATA_SCENES, scene_present

    assert set(STATIC_DATA_SCENES) == {n for n, (_, what) in DATA_SCENES.items() if what.endswith("(static)")}
    present = [n for n in DATA_SCENES if scene_present(n) and n != "tokyo"]  # (tokyo needs DracoPy, 141k)
    if not present:
        pytest.skip("the development data set is absent or hidden")
    for n in present:
        assert make_scene(n).static == (n in STATIC_DATA_SCENES), n
