"""Text mesh files (OBJ with its MTL material libraries, OFF, ASCII STL, PLY headers) in any
common encoding.

trimesh decodes text as UTF-8 and, when that fails, imports the optional ``charset_normalizer``
package to guess the encoding (and then drops whatever does not decode).  gridrt decodes the text
itself, with a fixed rule, and hands trimesh UTF-8:

1. a byte-order mark says the encoding: UTF-8, UTF-16 or UTF-32 (LE or BE);
2. without one, text whose every other byte is NUL is UTF-16 (LE or BE);
3. otherwise UTF-8 when the bytes are valid UTF-8, else Windows-1252 when they are valid
   Windows-1252, else Latin-1 (which decodes any bytes).

Latin-1 and Windows-1252 agree on every printable Latin-1 character (é, ü, ß, ...); Windows-1252
also reads the bytes 0x80-0x9F that Windows editors write (€, typographic quotes).

OBJ and OFF files are text throughout.  An STL file is re-encoded only when it is not a binary STL
(whose size is 84 + 50 x its triangle count) and not UTF-8 already; a PLY file only in its header
(comments, element names), unless a byte-order mark says the whole file is text.  Files that are
UTF-8 already reach trimesh unchanged.
"""

import codecs
import io

from ..errors import SceneFileError

__all__ = ["TEXT_EXTENSIONS", "decode_text", "utf8_source"]

#: Mesh file extensions whose text gridrt decodes before trimesh reads it.
TEXT_EXTENSIONS = (".obj", ".off", ".stl", ".ply")

_BOMS = (  # UTF-32 first: the UTF-32-LE mark begins with the UTF-16-LE one
    (codecs.BOM_UTF32_LE, "UTF-32-LE"),
    (codecs.BOM_UTF32_BE, "UTF-32-BE"),
    (codecs.BOM_UTF8, "UTF-8"),
    (codecs.BOM_UTF16_LE, "UTF-16-LE"),
    (codecs.BOM_UTF16_BE, "UTF-16-BE"),
)


def _bomless_utf16(raw):
    """"UTF-16-LE" / "UTF-16-BE" when the first bytes look like UTF-16 text without a mark (NUL in
    nearly every odd / even byte, hardly any in the others), else None."""
    head = raw[:4096]
    half = len(head) // 2
    if half < 2 or b"\x00" not in head:
        return None
    even = head[0:2 * half:2].count(0) / half
    odd = head[1:2 * half:2].count(0) / half
    if odd >= 0.9 and even <= 0.1:
        return "UTF-16-LE"
    if even >= 0.9 and odd <= 0.1:
        return "UTF-16-BE"
    return None


def decode_text(raw):
    """``(text, encoding)`` of the bytes ``raw`` by the rule in the module docstring; the byte-order
    mark is not part of ``text``.  UnicodeDecodeError only for text that a byte-order mark or its
    NUL bytes declare UTF-16/32 but that is not (e.g. truncated in the middle of a character)."""
    for bom, enc in _BOMS:
        if raw.startswith(bom):
            return raw[len(bom):].decode(enc), enc
    enc = _bomless_utf16(raw)
    if enc is not None:
        return raw.decode(enc), enc
    for enc in ("UTF-8", "Windows-1252"):
        try:
            return raw.decode(enc), enc
        except UnicodeDecodeError:
            pass
    return raw.decode("Latin-1"), "Latin-1"


def _is_utf8(raw):
    try:
        raw.decode("utf-8")
    except UnicodeDecodeError:
        return False
    return not raw.startswith(codecs.BOM_UTF8)


#: how an ASCII STL file starts: "solid", after a byte-order mark or as UTF-16 without one
_STL_TEXT_STARTS = tuple(bom for bom, _ in _BOMS) + (b"solid", "solid".encode("utf-16-le"),
                                                     "solid".encode("utf-16-be"))


def _binary_stl(raw):
    return len(raw) >= 84 and len(raw) == 84 + 50 * int.from_bytes(raw[80:84], "little")


def utf8_source(path):
    """``(source, keyword arguments)`` for ``trimesh.load`` of the mesh file ``path`` (a
    :class:`pathlib.Path` with one of :data:`TEXT_EXTENSIONS`): a file object of its text
    re-encoded as UTF-8 (see the module docstring), or the path itself when nothing needs
    re-encoding.  For OBJ files the keyword arguments hold a resolver that re-encodes the MTL
    material libraries the file names."""
    from trimesh.resolvers import FilePathResolver  # deferred: trimesh (about 0.6 s to load)

    class _Utf8Resolver(FilePathResolver):
        def get(self, name):
            data = super().get(name)
            if str(name).strip().lower().endswith(".mtl"):
                data = decode_text(data)[0].encode("utf-8")
            return data

    ext = path.suffix.lower()
    try:
        raw = path.read_bytes()
    except OSError as e:
        raise SceneFileError(path, f"cannot read the file ({e.strerror or e})") from e
    if ext == ".stl" and (_binary_stl(raw) or _is_utf8(raw) or not raw.startswith(_STL_TEXT_STARTS)):
        return str(path), {}  # binary (or malformed binary), or UTF-8 text already
    if ext == ".ply" and not any(raw.startswith(bom) for bom, _ in _BOMS):
        end = raw.find(b"end_header")
        head, body = (raw[:end], raw[end:]) if end >= 0 else (raw, b"")
        if _is_utf8(head):
            return str(path), {}
        return io.BytesIO(decode_text(head)[0].encode("utf-8") + body), {}
    try:
        text, _ = decode_text(raw)
    except UnicodeDecodeError as e:
        raise SceneFileError(path, f"malformed text: not valid {e.encoding.upper()} ({e.reason})") from e
    kw = {"resolver": _Utf8Resolver(str(path))} if ext == ".obj" else {}
    return io.BytesIO(text.encode("utf-8")), kw
