"""OBJ text that trimesh's reader misreads, rewritten as the format means it before trimesh reads it.

Found by reading OBJ files shaped like real exports (trimesh 4.x; each was
read without an error and without a word):

* **Relative indices.** ``f -3 -2 -1`` names the three vertices written
  last *before that line*; trimesh counts from the end of the file, so
  every face of an interleaved file named the same last vertices (1,800
  faces read as one, the rest dropped as "duplicates").
* **Faces with and without texture coordinates in one file** (a model with
  textured and plain parts): trimesh drops every texture coordinate. The
  faces without get (0, 0), as a glTF primitive without ``TEXCOORD_0``
  does here, and the report says how many.
* **Indented lines, or a tab after the keyword** (``v\t0 0 0``): trimesh
  reads no geometry at all ("empty file?") or only points.

:func:`normalized_obj` scans the file for these in blocks and returns None
when it holds none (the file is then read as it is, as before); otherwise
the rewritten text: every line's leading blanks gone and its words
separated by one space, every index of ``f``, ``l`` and ``p`` lines
absolute, and faces missing texture coordinates pointing at one ``vt 0 0``
added at the end (OBJ allows indices to refer forward).
"""

from __future__ import annotations

import re
from pathlib import Path

_BLOCK = 1 << 24
# Searched for in each block with a newline put before it (the patterns start at one, which Python's
# re finds fast as a literal prefix; ^ with MULTILINE tried every byte: 5 s for a 141 MB file).
# An indented or tabbed file is rewritten whatever else it holds, so the face patterns need only
# match a face line written plainly; a face's first corner says whether it has texture
# coordinates (exporters write all of a face's corners alike).
_INDENTED = (b"\n ", b"\n\t")
_TAB = b"\t"                             # any tab: rewritten (a tab between numbers reads, but is rare)
_RELATIVE = re.compile(rb"\n[flp] [^\n-]*-")       # a minus on a face, line or point line: an index
_FACE_WITH_UV = re.compile(rb"\nf -?\d+/-?\d")
_FACE_WITHOUT_UV = re.compile(rb"\nf -?\d+(?://| |\r|\n)")
_COUNTED = (b"v", b"vt", b"vn")
_NO_UV, _LONE_NO_UV = b"\x00", b"\x01"   # where a face's texture coordinates go, until known (see _rewrite)


def normalized_obj(path: Path) -> tuple[bytes | None, list[str]]:
    """(the OBJ's text rewritten, notes for the report), or (None, []) when the file needs none
    of the rewrites the module docstring lists."""
    found = dict.fromkeys(("indented", "relative", "with_uv", "without_uv"), False)
    rest = b""
    with open(path, "rb") as f:
        while True:
            block = f.read(_BLOCK)
            text = rest + block
            cut = text.rfind(b"\n") + 1 if block else len(text)     # whole lines; the last block all of it
            # A block's first line (the file's, or the one the last block's cut left) has no newline
            # before it for the patterns: scanned alone (a relative face there went unseen).
            _scan(b"\n" + text[:min(text.find(b"\n") + 1 or len(text), cut or len(text))], 0, None, found)
            _scan(text, 0, cut, found)
            rest = text[cut:]
            if _needed(found) or not block:
                break                             # rewritten whatever the rest holds, or all read
    if not _needed(found):
        return None, []
    return _rewrite(path.read_bytes())


def _needed(found: dict) -> bool:
    return found["indented"] or found["relative"] or (found["with_uv"] and found["without_uv"])


def _scan(text: bytes, start: int, end: int | None, found: dict) -> None:
    """Mark in ``found`` what ``text[start:end]`` (whole lines, each after a newline) shows."""
    end = len(text) if end is None else end
    found["indented"] = found["indented"] or any(text.find(w, start, end) >= 0 for w in _INDENTED) \
        or text.find(_TAB, start, end) >= 0
    for key, pattern in (("relative", _RELATIVE), ("with_uv", _FACE_WITH_UV), ("without_uv", _FACE_WITHOUT_UV)):
        found[key] = found[key] or pattern.search(text, start, end) is not None


def _rewrite(data: bytes) -> tuple[bytes, list[str]]:
    """The rewrite the module docstring describes, and its notes. A face missing texture
    coordinates is written with a placeholder where they go, which becomes the added ``vt 0 0``
    if any face has some, and is taken out again (the face as it was) if none has."""
    counts = dict.fromkeys(_COUNTED, 0)
    out, faces, without, relative_faces, textured = [], 0, 0, 0, False
    for raw in data.splitlines():
        words = raw.split()
        if not words:
            continue
        key = words[0]
        if key in counts:
            counts[key] += 1
            out.append(b" ".join(words))
        elif key in (b"f", b"l", b"p"):
            relative = b"-" in raw
            corners = [_absolute(w, counts) for w in words[1:]] if relative else [w.split(b"/") for w in words[1:]]
            if key == b"f":
                faces += 1
                relative_faces += relative
                if any(len(c) < 2 or not c[1] for c in corners):
                    without += 1
                    corners = [[c[0], _NO_UV] + c[2:] if len(c) > 1 else [c[0], _LONE_NO_UV] for c in corners]
                else:
                    textured = True
            out.append(key + b" " + b" ".join(b"/".join(c) for c in corners))
        else:
            # Names (usemtl, mtllib, o, g) keep their inner spaces; the keyword is followed by one
            # space, which trimesh looks for ("usemtl\tred" read as no material at all).
            out.append(b" ".join(raw.strip().split(None, 1)))
    notes = []
    if relative_faces:
        notes.append(f"{relative_faces:,} of its {faces:,} faces use relative (negative) indices: read as OBJ "
                     "defines them, from each face's line (trimesh alone counts them from the end of the file)")
    given = without if textured else 0
    if given:
        out.append(b"vt 0 0")
        notes.append(f"{given:,} of its {faces:,} faces have no texture coordinates where the others have them: "
                     "given (0, 0) (trimesh alone drops every texture coordinate of such a file)")
    text = b"\n".join(out) + b"\n"
    if without:
        dummy = b"%d" % (counts[b"vt"] + 1)
        text = text.replace(_NO_UV, dummy if given else b"").replace(b"/" + _LONE_NO_UV, b"/" + dummy if given
                                                                         else b"")
    return text, notes


def _absolute(corner: bytes, counts: dict) -> list[bytes]:
    """A face corner's ``v/vt/vn`` indices, each negative one made absolute (counted back from
    the vertices, texture coordinates or normals written so far)."""
    parts = corner.split(b"/")
    for i, part in enumerate(parts[:3]):
        if part.startswith(b"-"):
            try:
                parts[i] = b"%d" % (counts[_COUNTED[i]] + int(part) + 1)
            except ValueError:
                pass                               # not a number: left for trimesh to refuse
    return parts
