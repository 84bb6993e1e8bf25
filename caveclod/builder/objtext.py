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
_INDENTED = re.compile(rb"^[ \t]+[a-z]", re.MULTILINE)
_TAB_AFTER_KEYWORD = re.compile(rb"^[a-z]+\t", re.MULTILINE)
# Indented lines are rewritten anyway, so the rest also look past leading blanks; a face's first
# corner says whether it has texture coordinates (exporters write all of a face's corners alike).
_RELATIVE = re.compile(rb"^[ \t]*[flp][ \t][^\n]*?[ \t/]-\d", re.MULTILINE)
_FACE_WITH_UV = re.compile(rb"^[ \t]*f[ \t]+-?\d+/-?\d", re.MULTILINE)
_FACE_WITHOUT_UV = re.compile(rb"^[ \t]*f[ \t]+-?\d+(?://|[ \t]*\r?$|[ \t]+-?\d)", re.MULTILINE)
_COUNTED = (b"v", b"vt", b"vn")
_NO_UV = b"\x00"                        # stands for the added (0, 0) until its index is known


def normalized_obj(path: Path) -> tuple[bytes | None, list[str]]:
    """(the OBJ's text rewritten, notes for the report), or (None, []) when the file needs none
    of the rewrites the module docstring lists."""
    indented = relative = with_uv = without_uv = False
    rest = b""
    with open(path, "rb") as f:
        while True:
            block = f.read(_BLOCK)
            text = rest + block
            cut = text.rfind(b"\n") + 1 if block else len(text)     # whole lines; the last block all of it
            part = text[:cut]
            indented = indented or bool(_INDENTED.search(part) or _TAB_AFTER_KEYWORD.search(part))
            relative = relative or bool(_RELATIVE.search(part))
            with_uv = with_uv or bool(_FACE_WITH_UV.search(part))
            without_uv = without_uv or bool(_FACE_WITHOUT_UV.search(part))
            rest = text[cut:]
            if not block:
                break
    mixed = with_uv and without_uv
    if not (indented or relative or mixed):
        return None, []
    return _rewrite(path.read_bytes(), mixed)


def _rewrite(data: bytes, mixed: bool) -> tuple[bytes, list[str]]:
    counts = dict.fromkeys(_COUNTED, 0)
    out, faces, given, relative_faces = [], 0, 0, 0
    for raw in data.splitlines():
        words = raw.split()
        if not words:
            continue
        key = words[0]
        if key in counts:
            counts[key] += 1
            out.append(b" ".join(words))
        elif key in (b"f", b"l", b"p"):
            corners = [_absolute(w, counts) for w in words[1:]]
            if key == b"f":
                faces += 1
                relative_faces += any(w.startswith(b"-") or b"/-" in w for w in words[1:])
                if mixed and any(len(c) < 2 or not c[1] for c in corners):
                    given += 1
                    corners = [[c[0], _NO_UV] + c[2:] if len(c) > 1 else [c[0], _NO_UV] for c in corners]
            out.append(key + b" " + b" ".join(b"/".join(c) for c in corners))
        else:
            out.append(raw.strip())            # names (usemtl, mtllib, o, g) keep their inner spaces
    notes = []
    if relative_faces:
        notes.append(f"{relative_faces:,} of its {faces:,} faces use relative (negative) indices: read as OBJ "
                     "defines them, from each face's line (trimesh alone counts them from the end of the file)")
    if given:
        out.append(b"vt 0 0")
        notes.append(f"{given:,} of its {faces:,} faces have no texture coordinates where the others have them: "
                     "given (0, 0) (trimesh alone drops every texture coordinate of such a file)")
    text = b"\n".join(out) + b"\n"
    if given:
        text = text.replace(b"/" + _NO_UV, b"/%d" % (counts[b"vt"] + 1))
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
