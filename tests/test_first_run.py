"""A first run a newcomer can follow: what the README and the program tell a user to run works.

* every Python example of the documents runs as written (the ```python blocks of README.md and of
  each docs/*.md page, one program per document, run in a subprocess in an empty folder), and what
  it computes is right: its hits against the brute-force float64 caster, its image against the
  analytic silhouette of its sphere;
* the ``.venv/bin/gridrt ...`` commands of README.md, BENCHMARKS.md and docs/*.md are commands the
  parser takes, and every relative link of README.md and docs/*.md names a file that exists;
* the headless message of ``gridrt view`` prints a command that works as printed: named the way
  the viewer was started (``.venv/bin/gridrt`` from the repository root after the README's set-up,
  a full path elsewhere, ``gridrt`` when PATH finds it, the interpreter with ``-m gridrt``), and
  the printed dump, run by the shell as it is, writes its frames; the install hints name a pip
  that runs;
* the documented lists of built-in scenes, scene-file extensions and frame-folder extensions are
  :data:`gridrt.scene.BUILTIN_SCENES`, ``SCENE_EXTENSIONS`` and ``FRAME_EXTENSIONS``, and ``--help``
  and the error messages name the same;
* ``--help`` of every subcommand shows every option's default, and the defaults that help texts
  spell out in words are the parser's real ones.
"""

import argparse
import os
import re
import shlex
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from helpers.cli import all_parsers

REPO = Path(__file__).resolve().parents[1]
README = REPO / "README.md"
DOCS = REPO / "docs"
TESTS = Path(__file__).resolve().parent
SCRIPT = Path(sys.executable).parent / "gridrt"  # the console script beside the interpreter (.venv/bin)


def fenced_blocks(text):
    """(language, body) of every fenced code block of a Markdown text."""
    blocks, lang, body = [], None, []
    for ln in text.splitlines():
        if ln.startswith("```"):
            if lang is None:
                lang, body = ln[3:].strip(), []
            else:
                blocks.append((lang, "\n".join(body) + "\n"))
                lang = None
        elif lang is not None:
            body.append(ln)
    assert lang is None, "unclosed code block"
    return blocks


def documents():
    """README.md and the documentation pages it links to."""
    return [README] + sorted(DOCS.glob("*.md"))


def python_examples():
    """{document's path from the repository: its ```python blocks as one program} of every document
    that has any."""
    out = {}
    for doc in documents():
        blocks = [body for lang, body in fenced_blocks(doc.read_text(encoding="utf-8")) if lang == "python"]
        if blocks:
            out[doc.relative_to(REPO).as_posix()] = "\n".join(blocks)
    return out


EXAMPLES = python_examples()


def _env(path_dirs=None):
    """The environment of a user's shell: no display, PATH without the interpreter's folder (the
    README's set-up does not activate the virtual environment) unless ``path_dirs`` adds it."""
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    venv_bin = str(Path(sys.executable).parent)
    dirs = [d for d in env.get("PATH", "").split(os.pathsep) if d and os.path.realpath(d) != os.path.realpath(venv_bin)]
    env["PATH"] = os.pathsep.join(list(path_dirs or []) + dirs)
    return env


# ----------------------------------------------------------------------------- the documents' Python


CHECKS = textwrap.dedent('''
    import runpy, sys
    import numpy as np
    sys.path.insert(0, {tests!r})
    from reference import BACKGROUND, compare_hits, ref_camera_rays, ref_cast, to_u8


    def check_casts(ns):
        """its casts, against the float64 brute force over the same triangles (the mesh before any update)"""
        tris = np.asarray(ns["vertices"], np.float64)[np.asarray(ns["faces"])]
        ref = ref_cast(tris, np.asarray(ns["origins"], np.float64), np.asarray(ns["directions"], np.float64))
        hits = ns["hits"]
        diff = compare_hits(hits.t, hits.tri, ref)
        assert len(diff.bad) == 0, diff
        assert (hits.tri >= 0).any() and (hits.tri < 0).any(), "the example should show a hit and a miss"
        print("checked casts")


    def check_image(ns):
        """its image: the silhouette of the sphere it renders, from the camera it made (pixel centres)"""
        img, cam = ns["image"], ns["camera"]
        H, W = img.shape[:2]
        o, d = ref_camera_rays(cam.eye, cam.target, cam.up, cam.fov, W, H)
        v = np.asarray(ns["vertices"], np.float64)
        centre = 0.5 * (v.min(axis=0) + v.max(axis=0))
        radius = np.linalg.norm(v - centre, axis=1).max()
        oc = centre - o
        miss_dist = (np.linalg.norm(oc - (oc * d).sum(axis=1)[:, None] * d, axis=1) / radius).reshape(H, W)
        covered = (img[..., :3] != to_u8(BACKGROUND)).any(axis=2)
        inner, outer = miss_dist < 0.99, miss_dist > 1.001  # (the 5120 facets stay within 0.2% of the sphere)
        assert inner.sum() > 1000 and covered[inner].all(), "pixels whose rays hit the sphere show background"
        assert not covered[outer].any(), "pixels whose rays miss the sphere are not background"
        from PIL import Image
        assert (np.asarray(Image.open("sphere.png")) == img[..., :3]).all()
        print("checked image")


    ns = runpy.run_path("example.py")
    if "hits" in ns:
        check_casts(ns)
    if "image" in ns:
        check_image(ns)
''')


def test_the_documents_have_python_examples():
    """The README's short example and docs/api.md's whole one; between them a cast and an image."""
    assert "README.md" in EXAMPLES and "docs/api.md" in EXAMPLES, sorted(EXAMPLES)
    assert "image = " in EXAMPLES["docs/api.md"] and "hits = " in EXAMPLES["README.md"]


@pytest.mark.parametrize("doc", sorted(EXAMPLES))
def test_python_example_runs_as_written_and_is_right(doc, tmp_path):
    (tmp_path / "example.py").write_text(EXAMPLES[doc], encoding="utf-8")
    r = subprocess.run([sys.executable, "example.py"], cwd=tmp_path, capture_output=True, text=True, timeout=900)
    assert r.returncode == 0, r.stderr[-3000:]
    (tmp_path / "checks.py").write_text(CHECKS.format(tests=str(TESTS)), encoding="utf-8")
    r = subprocess.run([sys.executable, "checks.py"], cwd=tmp_path, capture_output=True, text=True, timeout=900)
    assert r.returncode == 0, r.stderr[-3000:]
    checked = r.stdout.split()
    assert "checked" in checked, f"{doc}'s example neither casts (hits) nor renders (image): nothing to check"
    if "image = " in EXAMPLES[doc]:
        assert (tmp_path / "sphere.png").is_file() and "image" in checked


@pytest.mark.parametrize("doc", sorted(EXAMPLES))
def test_python_example_needs_nothing_it_does_not_define(doc):
    """Every name an example uses is defined in it or imported by it (an example that runs on
    undefined ``vertices``, ``faces``, ``origins`` would fail a reader)."""
    import builtins
    import symtable

    table = symtable.symtable(EXAMPLES[doc], doc, "exec")
    free = [s.get_name() for s in table.get_symbols() if s.is_referenced() and not s.is_assigned()
            and not s.is_imported() and not hasattr(builtins, s.get_name())]
    assert free == []


# ----------------------------------------------------------------------------- the documents' commands


def build_parser():
    from gridrt.app.__main__ import build_parser

    return build_parser()


def documented_commands():
    """Every ``.venv/bin/gridrt ...`` command line of README.md, BENCHMARKS.md and docs/*.md (code
    blocks and inline code), as argument lists after the program."""
    cmds = []
    for doc in documents() + [REPO / "BENCHMARKS.md"]:
        text = doc.read_text(encoding="utf-8")
        lines = re.findall(r"^\.venv/bin/gridrt (.*)$", text, re.M)
        lines += re.findall(r"`\.venv/bin/gridrt ([^`]*)`", text)
        for ln in lines:
            cmds.append(shlex.split(ln.split("  #")[0].split(" #")[0]))
    return cmds


def test_documented_commands_parse():
    cmds = documented_commands()
    assert len(cmds) >= 12  # README: the headless dump and the tour; docs/cli.md: the examples; BENCHMARKS.md
    for args in cmds:
        if args[-1] == "--help":  # (argparse exits after printing help: run it for real)
            r = subprocess.run([sys.executable, "-m", "gridrt", *args], cwd=REPO, capture_output=True, text=True,
                               timeout=120)
            assert r.returncode == 0 and r.stdout.startswith("usage: gridrt"), r.stderr
            continue
        try:
            build_parser().parse_args(args)
        except SystemExit as e:
            pytest.fail(f"`.venv/bin/gridrt {shlex.join(args)}` does not parse (exit {e.code})")


def test_readme_setup_names_the_programs_it_installs():
    """The README's set-up installs into .venv without activating it, and every command the README
    and the docs pages then give names .venv/bin/...: no bare gridrt or pip command in a code
    block."""
    assert "python3 -m venv .venv && .venv/bin/pip install -q -e . && .venv/bin/gridrt view" in README.read_text(
        encoding="utf-8")
    for doc in documents():
        for lang, block in fenced_blocks(doc.read_text(encoding="utf-8")):
            for ln in block.splitlines():
                first = ln.split()[0] if ln.split() else ""
                assert first not in ("gridrt", "pip", "python"), f"{doc.name}: {ln}"


def relative_links(text):
    """The targets of a Markdown text's inline links and images that are neither web addresses nor
    anchors within the page, without their ``#anchor``."""
    text = "\n".join(outside_code(text))
    targets = re.findall(r"!?\[[^\]]*\]\(([^)\s]+)(?:\s+\"[^\"]*\")?\)", text)
    return [t.split("#", 1)[0] for t in targets
            if not re.match(r"[a-z][a-z0-9+.-]*:", t, re.I) and not t.startswith("#")]


def outside_code(text):
    """The lines of a Markdown text outside its fenced code blocks."""
    inside = False
    for ln in text.splitlines():
        if ln.startswith("```"):
            inside = not inside
        elif not inside:
            yield ln


def test_relative_links_name_files_that_exist():
    """Every relative link and picture of README.md and docs/*.md names a file or folder of the
    repository (relative to the document's folder)."""
    bad, n = [], 0
    for doc in documents():
        for target in relative_links(doc.read_text(encoding="utf-8")):
            n += 1
            if not (doc.parent / target).exists():
                bad.append(f"{doc.relative_to(REPO)}: {target}")
    assert not bad, "links to files that do not exist:\n" + "\n".join(bad)
    assert n >= 10  # (the README links the picture and every docs page)


def test_link_check_catches_a_broken_link():
    text = "See [a](docs/a.md#part), ![p](docs/images/p.png \"t\"), [w](https://x.org/y), [s](#top).\n```\n[c](no.md)\n```"
    assert relative_links(text) == ["docs/a.md", "docs/images/p.png"]


# ----------------------------------------------------------------------------- printed commands


def _headless_command(argv, cwd, env):
    r = subprocess.run(argv + ["view", "--scene", "marbles"], cwd=cwd, env=env, capture_output=True, text=True,
                       timeout=120)
    assert r.returncode == 3, r.stderr
    line = r.stderr.strip()
    assert "\n" not in line and "render headless instead: " in line, line
    return line.split("render headless instead: ", 1)[1]


@pytest.mark.skipif(not SCRIPT.is_file(), reason=f"no gridrt script beside {sys.executable}")
def test_headless_message_names_the_command_as_started():
    env = _env()
    rel = os.path.relpath(SCRIPT, REPO)
    # from the repository root after the README's set-up: .venv/bin/gridrt
    cmd = _headless_command([rel], REPO, env)
    args = shlex.split(cmd)
    assert args[0] == rel and (REPO / args[0]).resolve() == SCRIPT.resolve(), cmd
    assert build_parser().parse_args(args[1:]).command == "dump"
    # started through PATH: plain gridrt (PATH finds the same script)
    assert shlex.split(_headless_command(["gridrt"], REPO, _env([str(SCRIPT.parent)])))[0] == "gridrt"
    # python -m gridrt: the same interpreter, by its path, with -m gridrt
    args = shlex.split(_headless_command([sys.executable, "-m", "gridrt"], REPO, env))
    assert (REPO / args[0]).resolve() == Path(sys.executable).resolve() and args[1:4] == ["-m", "gridrt", "dump"]


@pytest.mark.slow
@pytest.mark.skipif(not SCRIPT.is_file(), reason=f"no gridrt script beside {sys.executable}")
def test_headless_message_command_runs_as_printed(tmp_path):
    """The printed dump, run by the shell exactly as printed, in the folder the viewer was started
    from (here outside the repository, so the script is named by its full path)."""
    env = _env()
    cmd = _headless_command([str(SCRIPT)], tmp_path, env)
    assert shlex.split(cmd)[0] == str(SCRIPT)
    r = subprocess.run(cmd, shell=True, cwd=tmp_path, env=env, capture_output=True, text=True, timeout=900)
    assert r.returncode == 0, r.stderr[-3000:]
    out = tmp_path / "out" / "marbles"
    assert sorted(p.name for p in out.glob("frame_*.png")) == [f"frame_{i:05d}.png" for i in range(60)]
    assert len((out / "stats.csv").read_text().splitlines()) == 61


def test_install_hints_name_a_pip_that_runs(tmp_path):
    from gridrt.app.bench.peers import INSTALL_HINT
    from gridrt.commands import pip_command
    from gridrt.scene.gltf import DRACO_HINT

    for hint, pkg in ((INSTALL_HINT, "embreex"), (DRACO_HINT, "DracoPy")):
        assert f"{pip_command()} install {pkg}" in hint
    r = subprocess.run(f"{pip_command()} --version", shell=True, cwd=os.getcwd(), env=_env(), capture_output=True,
                       text=True, timeout=120)
    assert r.returncode == 0 and "pip" in r.stdout, r.stderr


# ----------------------------------------------------------------------------- one list of formats


def scene_lists_document():
    """The one document (README.md or a docs page) that holds the scene lists."""
    holding = [doc for doc in documents() if "<!-- scene-lists:" in doc.read_text(encoding="utf-8")]
    assert len(holding) == 1, f"the scene lists should stand in one document, not {holding}"
    return holding[0]


def documented_scene_lists():
    text = scene_lists_document().read_text(encoding="utf-8")
    part = text.split("<!-- scene-lists:", 1)[1]
    items = re.findall(r"^- (.*?)(?=^- |^\n)", part, re.S | re.M)[:3]
    assert len(items) == 3, items
    codes = [re.findall(r"`([^`]*)`", it) for it in items]
    names = [c for c in codes[0] if re.fullmatch(r"[a-z_]+", c)]
    exts = [c for c in codes[1] if re.fullmatch(r"\.\w+", c)]
    frame_exts = [c for c in codes[2] if re.fullmatch(r"\.\w+", c)]
    return names, exts, frame_exts


def test_docs_list_the_scenes_and_formats_gridrt_has():
    from gridrt.scene import BUILTIN_SCENES, FRAME_EXTENSIONS, SCENE_EXTENSIONS

    names, exts, frame_exts = documented_scene_lists()
    assert sorted(names) == sorted(BUILTIN_SCENES)
    assert sorted(exts) == sorted(SCENE_EXTENSIONS)
    assert sorted(frame_exts) == sorted(FRAME_EXTENSIONS)


def _words(text):
    return set(re.findall(r"[\w.]+", text))


def test_help_and_errors_name_the_same_scenes_and_formats(tmp_path):
    from gridrt.errors import GridrtError
    from gridrt.scene import BUILTIN_SCENES, FRAME_EXTENSIONS, SCENE_EXTENSIONS, make_scene

    want = set(BUILTIN_SCENES) | set(SCENE_EXTENSIONS) | set(FRAME_EXTENSIONS)
    p = build_parser()
    sub = next(a for a in p._actions if isinstance(a, argparse._SubParsersAction))
    for name in ("dump", "view"):
        scene = next(a for a in sub.choices[name]._actions if "--scene" in a.option_strings)
        assert want <= _words(scene.help), (name, scene.help)
    bad = tmp_path / "mesh.xyz"
    bad.write_text("v 0 0 0\n")
    for source in ("no_such_scene", str(tmp_path / "missing.xyz"), str(bad)):
        with pytest.raises(GridrtError) as info:
            make_scene(source)
        assert want <= _words(str(info.value)), str(info.value)


def test_view_refuses_an_unknown_scene_naming_the_formats(tmp_path):
    from gridrt.scene import BUILTIN_SCENES, FRAME_EXTENSIONS, SCENE_EXTENSIONS

    env = _env()
    env["DISPLAY"] = ":987"  # set, so view gets as far as checking the scene (no window is opened)
    r = subprocess.run([sys.executable, "-m", "gridrt", "view", "--scene", "no_such_scene"], cwd=tmp_path, env=env,
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 2 and r.stderr.startswith("gridrt: error: unknown scene 'no_such_scene'"), r.stderr
    assert set(BUILTIN_SCENES) | set(SCENE_EXTENSIONS) | set(FRAME_EXTENSIONS) <= _words(r.stderr)


# ----------------------------------------------------------------------------- --help shows defaults


def option_help(parser, action):
    """The help text ``--help`` prints for one option, on one line."""
    fmt = parser._get_formatter()
    text = fmt._expand_help(action) if action.help is not argparse.SUPPRESS else ""
    return " ".join(text.split())


def shown(action):
    """A default as the user would type it."""
    d = action.default
    if isinstance(d, (tuple, list)):
        sep = "x" if getattr(action.type, "__name__", "") == "size" else ","
        return sep.join(f"{x:g}" if isinstance(x, float) else str(x) for x in d)
    return f"{d:g}" if isinstance(d, float) else str(d)


def test_help_shows_every_default():
    names = []
    for name, p in all_parsers():
        for a in p._actions:
            if not a.option_strings or isinstance(a, argparse._HelpAction) or a.help is argparse.SUPPRESS:
                continue
            if a.nargs == 0:  # switches (--shadows, --no-split, ...): off unless given
                continue
            text = option_help(p, a)
            names.append(f"{name} {a.option_strings[-1]}")
            assert "default" in text, f"{name} {a.option_strings[-1]}: {text!r} shows no default"
            if a.default is not None and "default" not in (a.help or ""):  # (defaults in words: the next test)
                assert f"(default: {shown(a)})" in text, f"{name} {a.option_strings[-1]}: {text!r} lacks {shown(a)}"
    assert len(names) > 60 and "gridrt dump --lambda" in names and "gridrt bench trade --lambdas" in names


def test_help_spells_defaults_as_the_parser_has_them():
    """Where a help text states a default in its own words ("default 4"), that is the real one."""
    for name, p in all_parsers():
        for a in p._actions:
            if not a.option_strings or a.default is None or isinstance(a.default, bool) or not a.help:
                continue
            for said in re.findall(r"default:? ([\w.,/x-]+)", a.help.replace("%(default)s", shown(a))):
                said = said.rstrip(".,;")
                if said in ("auto", "all", "both", "none", "off", "on") or said == shown(a):  # (behaviours)
                    continue
                try:
                    assert float(eval(said, {})) == pytest.approx(float(a.default)), (name, a.option_strings, said)
                except (SyntaxError, NameError, TypeError, ValueError):
                    pytest.fail(f"{name} {a.option_strings[-1]}: help says default {said!r}, the parser has "
                                f"{a.default!r}")


def test_help_of_a_subcommand_prints_defaults_through_the_cli(tmp_path):
    r = subprocess.run([sys.executable, "-m", "gridrt", "dump", "--help"], cwd=tmp_path, capture_output=True,
                       text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    text = " ".join(r.stdout.split())
    from gridrt.config import GridParams, RenderParams

    g, rp = GridParams(), RenderParams()
    assert f"(default: {g.strategy})" in text and f"(default: {rp.shading})" in text
    assert "(default: out/dump)" in text and "(default: 1024x768)" in text


# ----------------------------------------------------------------------------- the Layout (docs/layout.md)


def layout_paths():
    """(path, indent) of every path the Layout block of docs/layout.md names at a line's start (a
    folder ``x/`` or a file ``x.py``/``x.toml``; indented lines name paths inside the folder above
    them), and the ``*.py`` files named anywhere on the engine's indented lines."""
    text = (DOCS / "layout.md").read_text(encoding="utf-8")
    block = next(body for lang, body in fenced_blocks(text))
    named, top = [], None
    for ln in block.splitlines():
        if not ln.strip():
            continue
        indent = len(ln) - len(ln.lstrip())
        first = ln.split()[0].rstrip(",")
        if indent == 0:
            top = first
            named.append(first)
        elif indent == 2 and re.fullmatch(r"[\w.]+/?", first):
            named.append(top + first)
            if first.endswith(".py"):  # a line of files: every one it names
                named += [top + f for f in re.findall(r"\b(\w+\.py)\b", ln)]
    return named


def test_layout_is_the_tree():
    named = layout_paths()
    for rel in named:
        assert (REPO / rel).exists(), f"docs/layout.md names {rel}, which is not in the repository"
    tracked = subprocess.run(["git", "ls-files"], cwd=REPO, capture_output=True, text=True).stdout.split()
    if not tracked:
        pytest.skip("not a git checkout")
    top = {p.split("/")[0] + ("/" if "/" in p else "") for p in tracked if not p.startswith(".")}
    top -= {"README.md", "BENCHMARKS.md"}  # (the documents themselves)
    assert top <= set(named), f"top-level paths the Layout omits: {sorted(top - set(named))}"
    packages = {"/".join(p.split("/")[:2]) + "/" for p in tracked
                if p.split("/")[0] in ("engine", "app") and p.count("/") >= 2 and p.endswith("/__init__.py")
                and p.count("/") == 2}
    assert packages <= set(named), f"subpackages the Layout omits: {sorted(packages - set(named))}"


# ----------------------------------------------------------------------------- short table cells


def long_cells(text, limit=160):
    """The markdown table cells of ``text`` longer than one sentence: over ``limit`` characters, or
    holding a sentence's end followed by another sentence."""
    bad = []
    for ln in text.splitlines():
        if not ln.startswith("|") or re.fullmatch(r"\|[\s:|-]+\|", ln.strip()):
            continue
        for cell in re.split(r"(?<!\\)\|", ln.strip())[1:-1]:
            cell = cell.strip()
            if len(cell) > limit or re.search(r"[a-z0-9)][.;!?] +[A-Z]", cell):
                bad.append(cell)
    return bad


def test_document_table_cells_hold_at_most_a_sentence():
    for doc in [README, *sorted(DOCS.glob("**/*.md"))]:
        bad = long_cells(doc.read_text(encoding="utf-8"))
        assert not bad, f"{doc.relative_to(REPO)}: table cells longer than a sentence: {bad}"


def test_long_cell_check_catches_a_planted_cell():
    table = "| a | b |\n|---|---|\n| short | one sentence. Then another one. |\n| x | " + "y" * 200 + " |\n"
    assert long_cells(table) == ["one sentence. Then another one.", "y" * 200]
    assert long_cells("| a | b |\n|---|---|\n| e.g. this | 1.5 ms |\n") == []
