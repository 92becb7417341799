"""The OBJ reader: :func:`read_obj`, which :func:`gridrt.scene.loader.load_mesh` calls for .obj files.

Polygons (quads, pentagons, ...) are triangulated as fans ``(0, i, i + 1)`` in file order.  Looks
(a :class:`gridrt.scene.surface.Surface` with one row per face): the materials of the MTL
libraries (``mtllib``) that the faces name (``usemtl``): ``Kd`` is the diffuse colour and
``map_Kd`` its texture (a path relative to the .mtl file, multiplied by ``Kd`` as the MTL
specification says; ``-clamp on`` clamps it, the other options are ignored); ``vt`` texture
coordinates (stored as ``(u, 1 - v)``: OBJ's v goes up the image), ``vn`` normals (normalised) and
``v x y z r g b`` vertex colours, per face corner.  MTL ``Ka`` is ignored: exporters disagree about
it (1 1 1, 0 0 0, a copy of Kd, or nothing), so every material's ambient colour is
``AMBIENT_FRACTION * diffuse``.  A missing library or texture, or one outside the OBJ file's
folder (:mod:`gridrt.scene.files`), or a texture that cannot be read, warns
(:class:`gridrt.scene.surface.TextureWarning`) and the mesh loads without it; faces without a
material, or naming one no library defines, get the default grey (:data:`DEFAULT_DIFFUSE`).  An
OBJ file with none of usemtl, vt, vn or vertex colours has no surface (None).
"""

import math
import warnings
from pathlib import Path

import numpy as np

from ..errors import InputError, SceneFileError
from .files import OutsideReference, SceneFolder, os_problem, read_regular, read_scene_file
from .mesh import AMBIENT_FRACTION, DEFAULT_DIFFUSE, _unit_rows
from .surface import Surface, TextureWarning, load_texture
from .textenc import decode_text

# ----------------------------------------------------------------------------- OBJ
#
# Two readers fill the same record (_ObjParse): a vectorised one for the usual file (every
# statement at the start of its line, numbers only, v / v/vt / v//vn / v/vt/vn corners), which
# gives up (None) on anything else, and a line-by-line one that reads every file and names the
# line of the first problem.

class _ObjError(Exception):
    """A malformed statement: (keyword, its number among the statements of that keyword,
    problem); read_obj turns it into a SceneFileError naming the line."""

    def __init__(self, key, row, problem):
        super().__init__(problem)
        self.key, self.row, self.problem = key, row, problem


class _ObjParse:
    """What the readers read: ``pos`` (V, 6) float64 (NaN past a row's numbers) and ``vcount``
    (V,) numbers per v line; ``lens`` (F,) corners per face; ``fv``, ``ft``, ``fn`` (C,) indices
    per corner as written (1-based, negative = relative, 0 = none); ``bases`` (F, 3) v, vt, vn lines
    before each face; ``tex()`` / ``nrm()`` the vt (T, 2) and vn (N, 3) rows on demand; ``usemtl``
    [(faces before it, name)], ``mtllibs`` [name]."""


_OBJ_WS = np.zeros(257, bool)
_OBJ_WS[[9, 10, 11, 12, 13, 32]] = True


def _obj_split(line):
    """(keyword, rest) of an OBJ line by the general rule, or None for blank lines and comments."""
    s = line.strip()
    if not s or s[0] == "#":
        return None
    parts = s.split(None, 1)
    return parts[0], (parts[1] if len(parts) > 1 else "")


def _obj_line_number(text, key, row):
    """1-based line number of the ``row``-th statement ``key`` (0-based) of the OBJ ``text``."""
    seen = 0
    for i, line in enumerate(text.split("\n")):
        kv = _obj_split(line)
        if kv is not None and kv[0] == key:
            if seen == row:
                return i + 1
            seen += 1
    return None


def _obj_lex(a):
    """(tokens per line (L,), offsets of the tokens' first bytes) of ``a``, uint8 text of whole
    lines (each ends with a newline)."""
    ws = _OBJ_WS[a]
    start = ~ws
    start[1:] &= ws[:-1]
    first = np.flatnonzero(start)
    ends = np.searchsorted(first, np.flatnonzero(a == 10))
    return np.diff(ends, prepend=0), first


def _obj_fast_numbers(a, least, most):
    """(values (R, most) with NaN past each row's numbers, counts (R,)) of rows of numbers, uint8
    text of whole lines; None when a row has fewer than ``least`` numbers or something else."""
    per_line, first_byte = _obj_lex(a)
    try:
        vals = np.fromstring(a.tobytes(), sep=" ")
    except ValueError:
        return None
    if len(vals) != len(first_byte) or (len(per_line) and per_line.min() < least):
        return None
    first = np.cumsum(per_line) - per_line
    out = np.full((len(per_line), most), np.nan)
    for j in range(most):
        have = per_line > j
        out[have, j] = vals[first[have] + j]
    return out, per_line


def _obj_fast_faces(a):
    """(lens, v, vt, vn) of face lines (uint8 text of whole lines, keyword removed), or None."""
    b = a.tobytes().replace(b"//", b"/0/")
    a = np.frombuffer(b, np.uint8)
    lens, first_byte = _obj_lex(a)
    owner = np.searchsorted(first_byte, np.flatnonzero(a == 47), side="right") - 1  # the token of every '/'
    fields = np.bincount(owner, minlength=len(first_byte)) + 1
    try:
        vals = np.fromstring(b.replace(b"/", b" "), sep=" ", dtype=np.int64)
    except ValueError:
        return None
    if len(vals) != int(fields.sum()) or (fields > 3).any() or (len(lens) and lens.min() < 3):
        return None
    first = np.cumsum(fields) - fields
    v = vals[first]
    last = max(len(vals) - 1, 0)
    vt = np.where(fields >= 2, vals[np.minimum(first + 1, last)], 0)
    vn = np.where(fields >= 3, vals[np.minimum(first + 2, last)], 0)
    if (v == 0).any():
        return None
    return lens, v, vt, vn


def _obj_parse_fast(text):
    """_ObjParse of the usual OBJ file (see above), or None."""
    raw = text.encode("utf-8", "replace")
    if not raw.endswith(b"\n"):
        raw += b"\n"
    n = len(raw)
    b = np.frombuffer(raw + b"\n\n\n", np.uint8)
    nl = np.flatnonzero(b[:n] == 10)
    starts = np.empty(len(nl), np.int64)
    starts[0] = 0
    starts[1:] = nl[:-1] + 1
    c0, c1, c2 = b[starts], b[starts + 1], b[starts + 2]
    v_, f_ = c0 == ord("v"), c0 == ord("f")
    kinds = {"v": (v_ & _OBJ_WS[c1], 2), "vt": (v_ & (c1 == ord("t")) & _OBJ_WS[c2], 3),
             "vn": (v_ & (c1 == ord("n")) & _OBJ_WS[c2], 3), "f": (f_ & _OBJ_WS[c1], 2)}
    known = kinds["v"][0] | kinds["vt"][0] | kinds["vn"][0] | kinds["f"][0]
    # the other lines that may matter: usemtl, mtllib, and indented ones (any statement)
    look = np.flatnonzero(~known & (nl > starts) & ((c0 == ord("u")) | (c0 == ord("m")) | _OBJ_WS[c0]))
    fcount = np.cumsum(kinds["f"][0])
    r = _ObjParse()
    r.usemtl, r.mtllibs = [], []
    for li in look.tolist():
        kv = _obj_split(raw[starts[li]:nl[li]].decode("utf-8", "replace"))
        if kv is None:
            continue
        if kv[0] in kinds:
            return None
        if kv[0] == "usemtl":
            r.usemtl.append((int(fcount[li]), kv[1].strip()))
        elif kv[0] == "mtllib":
            r.mtllibs.append(kv[1].strip())

    line_len = nl - starts + 1

    def rows(key):
        """The text of the ``key`` lines without their keyword, newlines kept (uint8)."""
        sel, skip = kinds[key]
        if not sel.any():
            return np.zeros(0, np.uint8)
        mask = np.repeat(sel, line_len)
        for j in range(skip):
            mask[starts[sel] + j] = False
        a = b[:n][mask]
        return a if int((a == 10).sum()) == int(sel.sum()) else None  # a keyword that ends its line

    subs = {k: rows(k) for k in kinds}
    if any(s is None for s in subs.values()):
        return None
    got = _obj_fast_numbers(subs["v"], 3, 6)
    faces = _obj_fast_faces(subs["f"])
    if got is None or faces is None:
        return None
    r.pos, r.vcount = got
    r.lens, r.fv, r.ft, r.fn = faces
    f_lines = kinds["f"][0]
    r.bases = np.stack([np.cumsum(kinds[k][0])[f_lines] for k in ("v", "vt", "vn")], axis=1)

    def attribute(key, least, most):
        def read():
            got = _obj_fast_numbers(subs[key], least, most)
            if got is None:  # the line-by-line reader names the problem
                return _obj_number_rows(subs[key].tobytes().decode("utf-8", "replace").split("\n")[:-1], key,
                                        least, most)[0]
            return got[0]
        return read

    r.tex, r.nrm = attribute("vt", 1, 2), attribute("vn", 3, 3)
    return r


def _obj_number_rows(rows, key, least, most):
    """(values (R, most) float64 with NaN past each row's numbers, counts (R,)) of rows of numbers
    (text after the keyword); _ObjError for a row with fewer than ``least`` numbers or something
    that is not a number."""
    out = np.full((len(rows), most), np.nan)
    counts = np.zeros(len(rows), np.int64)
    for r, row in enumerate(rows):
        toks = row.split("#", 1)[0].split()
        try:
            nums = [float(x) for x in toks]
        except ValueError:
            raise _ObjError(key, r, f"'{key} {row.strip()}': not a number") from None
        if len(nums) < least:
            raise _ObjError(key, r, f"'{key} {row.strip()}': {key} needs {least} numbers, got {len(nums)}")
        counts[r] = len(nums)
        out[r, :min(len(nums), most)] = nums[:most]
    return out, counts


def _obj_face_rows(rows):
    """(corners per face (F,), v, vt, vn indices per corner (C,) int64 as written) of face rows."""
    lens = np.zeros(len(rows), np.int64)
    out = ([], [], [])
    for r, row in enumerate(rows):
        toks = row.split("#", 1)[0].split()
        if len(toks) < 3:
            raise _ObjError("f", r, f"'f {row.strip()}': a face needs at least 3 corners, got {len(toks)}")
        for tok in toks:
            parts = tok.split("/")
            if len(parts) > 3 or not parts[0]:
                raise _ObjError("f", r, f"'f {row.strip()}': malformed corner {tok!r} (v, v/vt, v//vn or v/vt/vn)")
            try:
                ids = [int(x) if x else 0 for x in parts] + [0] * (3 - len(parts))
            except ValueError:
                raise _ObjError("f", r, f"'f {row.strip()}': corner {tok!r} is not made of integer indices") from None
            if ids[0] == 0:
                raise _ObjError("f", r, f"'f {row.strip()}': vertex index 0 (OBJ indices start at 1)")
            if any(abs(i) >= 2 ** 62 for i in ids):
                raise _ObjError("f", r, f"'f {row.strip()}': index {tok!r} out of range")
            for o, i in zip(out, ids):
                o.append(i)
        lens[r] = len(toks)
    return (lens,) + tuple(np.asarray(o, np.int64) for o in out)


def _obj_parse_lines(text):
    """_ObjParse of any OBJ file, line by line; _ObjError for a malformed statement."""
    rows = {"v": [], "vt": [], "vn": [], "f": []}
    r = _ObjParse()
    r.usemtl, r.mtllibs = [], []
    bases = []
    for line in text.split("\n"):
        kv = _obj_split(line)
        if kv is None:
            continue
        key, rest = kv
        if key in rows:
            if key == "f":
                bases.append((len(rows["v"]), len(rows["vt"]), len(rows["vn"])))
            rows[key].append(rest)
        elif key == "usemtl":
            r.usemtl.append((len(rows["f"]), rest.strip()))
        elif key == "mtllib":
            r.mtllibs.append(rest.strip())
    r.pos, r.vcount = _obj_number_rows(rows["v"], "v", 3, 6)
    r.lens, r.fv, r.ft, r.fn = _obj_face_rows(rows["f"])
    r.bases = np.asarray(bases, np.int64).reshape(-1, 3)
    r.tex = lambda: _obj_number_rows(rows["vt"], "vt", 1, 2)[0]
    r.nrm = lambda: _obj_number_rows(rows["vn"], "vn", 3, 3)[0]
    return r


def _obj_resolve(raw, count, bases, key, what, corner_face):
    """0-based indices (-1: none) of the OBJ indices ``raw`` ((C,): 1-based, negative = relative to
    ``bases`` of the corner's face, 0 = none) into ``count`` entries; _ObjError naming the first
    index out of range."""
    idx = np.where(raw > 0, raw - 1, -1)
    neg = raw < 0
    if neg.any():
        idx[neg] = bases[corner_face[neg]] + raw[neg]
    bad = (raw != 0) & ((idx < 0) | (idx >= count))
    if bad.any():
        c = int(np.argmax(bad))
        if raw[c] < 0:
            have = f"{int(bases[corner_face[c]])} {key} lines before this face"
            raise _ObjError("f", int(corner_face[c]), f"{what} index {int(raw[c])} (relative) out of range: the "
                                                      f"file has {have}")
        raise _ObjError("f", int(corner_face[c]), f"{what} index {int(raw[c])} out of range: the file has {count} "
                                                  f"{key} lines")
    return idx


def read_obj(path, looks=True, folder=None):
    """Read an OBJ file: ``(vertices (V, 3) float64, faces (F, 3) int64, surface or None)``.

    The vertices are the ``v`` positions that faces use, in file order (unused ones are dropped,
    each position is one vertex whatever its vt/vn); polygons are triangulated as fans
    ``(0, i, i + 1)``, in file order; ``surface`` (see the module docstring; None without looks or
    with ``looks=False``) has one row per triangle.  Indices may be negative (relative to the
    statements before the face).  Raises SceneFileError naming the file (and the line) for a
    malformed statement or an index out of range, the MTL file (and the line, not its text) for a
    malformed colour.  The MTL libraries and their textures must lie inside ``folder`` (a
    :class:`gridrt.scene.files.SceneFolder`; default: the OBJ file's folder, untrusted): one
    outside is dropped with a TextureWarning.
    """
    p = Path(path)
    folder = SceneFolder(p) if folder is None else folder
    raw = read_scene_file(p)
    try:
        text = decode_text(raw)[0]
    except UnicodeDecodeError as e:
        raise SceneFileError(p, f"malformed text: not valid {e.encoding.upper()} ({e.reason})") from e
    if "\r" in text:
        text = text.replace("\r\n", "\n").replace("\r", "\n")
    if "\\\n" in text:
        text = text.replace("\\\n", " ")
    try:
        # np.errstate: extreme numbers (1e300 -> float32, inf - inf) must not print RuntimeWarnings;
        # what is not finite is refused below or by Mesh
        with np.errstate(all="ignore"):
            parsed = _obj_parse_fast(text) or _obj_parse_lines(text)
            if not len(parsed.lens):
                nv = len(parsed.pos)
                raise SceneFileError(p, "file contains no triangles (no faces" + (f", only {nv} vertices)" if nv
                                                                                  else ")"))
            return _obj_build(p, parsed, looks, folder)
    except _ObjError as e:
        n = _obj_line_number(text, e.key, e.row)
        raise SceneFileError(p, (f"line {n}: " if n else "") + e.problem) from None


def _obj_build(p, r, looks, folder):
    lens, F = r.lens, len(r.lens)
    corner_face = np.repeat(np.arange(F), lens)
    vi = _obj_resolve(r.fv, len(r.pos), r.bases[:, 0], "v", "vertex", corner_face)
    # triangle fans: polygon f with n corners -> (0, i, i + 1), i = 1 .. n - 2
    ntri = lens - 2
    first = np.cumsum(lens) - lens
    tri_face = np.repeat(np.arange(F), ntri)
    i = np.arange(len(tri_face)) - np.repeat(np.cumsum(ntri) - ntri, ntri) + 1
    c0 = first[tri_face]
    corners = np.stack([c0, c0 + i, c0 + i + 1], axis=1)
    used = np.zeros(len(r.pos), bool)
    used[vi] = True
    remap = np.cumsum(used) - 1
    vertices = r.pos[used, :3]
    faces = remap[vi[corners]]
    if not looks:
        return vertices, faces, None
    has_t, has_n = bool((r.ft != 0).any()), bool((r.fn != 0).any())
    colored = bool(len(r.vcount)) and r.vcount.min() == r.vcount.max() == 6
    if not (r.usemtl or has_t or has_n or colored):
        return vertices, faces, None
    uv = normals = colors = None
    # attribute tables get a last row of zeros for the corners without one (index -1)
    if has_t:
        tex = r.tex()
        tex[np.isnan(tex)] = 0.0  # "vt u": v = 0
        ti = _obj_resolve(r.ft, len(tex), r.bases[:, 1], "vt", "texture coordinate", corner_face)
        table = np.zeros((len(tex) + 1, 2), np.float64)
        table[:-1, 0], table[:-1, 1] = tex[:, 0], 1.0 - tex[:, 1]
        uv = table[ti][corners].astype(np.float32)
        if not np.isfinite(uv).all():
            raise SceneFileError(p, "a face uses a texture coordinate (vt) that is NaN, infinite or beyond float32")
    if has_n:
        nrm = r.nrm()
        ni = _obj_resolve(r.fn, len(nrm), r.bases[:, 2], "vn", "normal", corner_face)
        table = np.zeros((len(nrm) + 1, 3), np.float32)
        table[:-1] = _unit_rows(nrm)
        normals = table[ni][corners]
        if not np.isfinite(normals).all():
            raise SceneFileError(p, "a face uses a normal (vn) that is NaN or infinite")
    if colored:
        vc = r.pos[:, 3:6]
        if np.isfinite(vc).all():
            if vc.max() > 1.0:  # 0-255 colours
                vc = vc / 255.0
            colors = np.clip(vc, 0.0, 1.0)[vi][corners].astype(np.float32)
    # materials: one slot per usemtl name, slot -1 for the faces before the first usemtl
    names = sorted({name for _, name in r.usemtl})
    slot = np.full(F, -1, np.int64)
    if r.usemtl:
        number = {name: k for k, name in enumerate(names)}
        starts = np.array([start for start, _ in r.usemtl], np.int64)
        ids = np.array([number[name] for _, name in r.usemtl], np.int64)
        last = np.searchsorted(starts, np.arange(F), side="right") - 1  # the last usemtl before each face
        slot = np.where(last >= 0, ids[np.maximum(last, 0)], -1)
    library, complete = _obj_materials(p, r.mtllibs, folder) if r.usemtl else ({}, True)
    unknown = sorted(n for n in names if n not in library and n)
    if unknown and complete:
        warnings.warn(f"{p}: material{'s' if len(unknown) > 1 else ''} {', '.join(map(repr, unknown))} not defined "
                      "by its material libraries; drawn in the default grey", TextureWarning, stacklevel=3)
    table, textures, tex_ids = {}, [], {}
    slot_row = np.zeros(len(names) + 1, np.int64)  # slot_row[slot] (slot -1 is the last entry)
    for s in np.unique(slot).tolist():  # the slots some face uses
        kd, tex = library.get(names[s], (None, None)) if s >= 0 else (None, None)
        if tex is not None and uv is None:
            tex = None  # a texture needs vt coordinates
        if kd is None:
            kd = (1.0, 1.0, 1.0) if tex is not None else DEFAULT_DIFFUSE
        ti = -1
        if tex is not None:
            ti = tex_ids.setdefault(id(tex), len(textures))
            if ti == len(textures):
                textures.append(tex)
        key = (tuple(np.float32(kd).tolist()), ti)
        slot_row[s] = table.setdefault(key, len(table))
    rows = sorted(table.items(), key=lambda kv: kv[1])
    diffuse = np.array([k[0] for k, _ in rows], np.float32)
    material = slot_row[slot][tri_face].astype(np.int32)
    try:
        surface = Surface(material, diffuse, (np.float32(AMBIENT_FRACTION) * diffuse).astype(np.float32),
                          np.array([k[1] for k, _ in rows], np.int32), tuple(textures), uv, colors, normals)
    except InputError as e:
        raise SceneFileError(p, str(e)) from e
    return vertices, faces, surface


_MAP_OPTIONS = {"-blendu": 1, "-blendv": 1, "-cc": 1, "-clamp": 1, "-mm": 2, "-bm": 1, "-boost": 1, "-texres": 1,
                "-imfchan": 1, "-type": 1, "-o": 3, "-s": 3, "-t": 3}


def _map_kd(rest):
    """(file name, clamp) of a ``map_Kd`` statement's arguments (options skipped)."""
    toks = rest.split()
    clamp = False
    k = 0
    while k < len(toks) and toks[k].lower() in _MAP_OPTIONS and k + 1 < len(toks):
        opt = toks[k].lower()
        n = _MAP_OPTIONS[opt]
        if opt in ("-o", "-s", "-t"):  # 1 to 3 numbers
            m = 0
            while m < n and k + 1 + m < len(toks) - 1:
                try:
                    float(toks[k + 1 + m])
                except ValueError:
                    break
                m += 1
            n = max(m, 1)
        if opt == "-clamp":
            clamp = toks[k + 1].lower() == "on"
        k += 1 + n
    return " ".join(toks[k:]), clamp


def _find_file(folder, name):
    """The file ``name`` (relative to ``folder``; backslashes as separators), or a file of that name
    (any case) in ``folder`` itself, or None."""
    name = name.strip().strip('"')
    if not name:
        return None
    for cand in (folder / name, folder / name.replace("\\", "/")):
        if cand.is_file():
            return cand
    base = name.replace("\\", "/").rsplit("/", 1)[-1].lower()
    try:
        for q in folder.iterdir():
            if q.name.lower() == base and q.is_file():
                return q
    except OSError:
        pass
    return None


def _obj_materials(obj_path, mtllibs, scene):
    """``({material name: (Kd or None, Texture or None)}, all libraries read)`` of the MTL
    libraries an OBJ file names, relative to its folder; a missing library, or one or a texture
    outside the SceneFolder ``scene``, warns (TextureWarning) and is left out; a malformed colour
    raises SceneFileError naming the MTL file and line (not its text: the file may be none)."""
    folder = obj_path.parent
    out = {}
    textures = {}
    complete = True
    for lib in mtllibs:
        found = _find_file(folder, lib)
        files = [found] if found is not None else [_find_file(folder, n) for n in lib.split()]
        if found is None and not all(f is not None for f in files):
            complete = False
            warnings.warn(f"material library {lib!r} (named by {obj_path}): file not found; its materials are "
                          "drawn in the default grey", TextureWarning, stacklevel=4)
            files = [f for f in files if f is not None]
        for mtl in files:
            try:
                scene.check(mtl, "material library", lib, obj_path)
                text = decode_text(read_regular(mtl))[0]
            except OutsideReference as e:
                complete = False
                warnings.warn(f"{e}; its materials are drawn in the default grey", TextureWarning, stacklevel=4)
                continue
            except (OSError, UnicodeDecodeError) as e:
                complete = False
                why = os_problem(e) if isinstance(e, OSError) else f"cannot be read ({e.reason})"
                warnings.warn(f"material library {mtl}: {why}; its materials are drawn in the default grey",
                              TextureWarning, stacklevel=4)
                continue
            name, kd, tex = None, None, None

            def close():
                if name is not None:
                    out[name] = (kd, tex)

            for n, line in enumerate(text.splitlines(), 1):
                kv = _obj_split(line)
                if kv is None:
                    continue
                key, rest = kv[0].lower(), kv[1]
                if key == "newmtl":
                    close()
                    name, kd, tex = rest.strip(), None, None
                elif name is None:
                    continue
                elif key == "kd":
                    toks = rest.split("#", 1)[0].split()
                    if toks and toks[0].lower() in ("spectral", "xyz"):
                        continue  # not RGB: left at the default
                    try:
                        vals = [float(x) for x in toks]
                    except ValueError:
                        vals = []
                    if len(vals) == 1:
                        vals = vals * 3
                    if len(vals) < 3 or not all(math.isfinite(x) and x >= 0 for x in vals[:3]):
                        raise SceneFileError(mtl, f"line {n}: Kd needs 3 numbers >= 0")
                    kd = tuple(vals[:3])
                elif key == "map_kd":
                    file, clamp = _map_kd(rest)
                    img = _find_file(mtl.parent, file)
                    where = img if img is not None else mtl.parent / file.replace("\\", "/")
                    k = (str(where), clamp)
                    if not scene.is_inside(where):
                        warnings.warn(f"texture {str(where) + (' (clamped)' if clamp else '')}: "
                                      f"{scene.refusal('map_Kd', file, mtl).problem}; drawn without it",
                                      TextureWarning, stacklevel=4)
                        textures[k] = None
                    if k not in textures:
                        textures[k] = load_texture(where, ("clamp", "clamp") if clamp else ("repeat", "repeat"),
                                                   name=str(where) + (" (clamped)" if clamp else ""))
                    tex = textures[k]
            close()
    return out, complete
