"""Mesh files (OBJ, PLY, GLB/glTF, STL, OFF, anything trimesh reads) -> SourceMesh.

Two entry points:

* :func:`load_mesh_file` reads a file through trimesh and turns every problem
  into an :class:`~caveclod.errors.InputError` with a one-line message.
* :func:`source_from_trimesh` converts an in-memory ``trimesh.Trimesh`` or
  ``trimesh.Scene``.

Both end in the same cleaning pipeline (see :func:`_clean`):

1. positions are welded exactly: bitwise-equal xyz rows become one position
   (after turning -0.0 into +0.0, so that the two zeros do not open a crack);
2. vertices whose whole attribute row (position id, normal, uv, colour) is
   bitwise equal are merged;
3. faces that use a position twice are dropped (degenerate after welding);
4. faces repeating an earlier face (same positions in the same cyclic order,
   same material) are dropped;
5. vertices and positions that no face uses are dropped and renumbered.

Every repair is one line in :attr:`SourceMesh.notes` with its count.
Everything is vectorised numpy: no Python loop runs per face or per vertex.
"""

from __future__ import annotations

import io
import os
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import InputError
from .quiet import quiet_reading
from .source import FLOAT32_MAX, MAX_COORDINATE, SourceMesh, out_of_range_rows

__all__ = ["load_mesh_file", "source_from_trimesh"]

# Longest message fragment quoted from a trimesh exception; keeps errors on one line.
_MAX_CAUSE_CHARS = 200
# A normal shorter than this is treated as zero-length (no usable direction).
_MIN_NORMAL_LENGTH = 1e-12
# Normals whose length is off by more than this are reported as renormalised.
_UNIT_TOLERANCE = 1e-3


# --------------------------------------------------------------------------
# public API
# --------------------------------------------------------------------------


def load_mesh_file(path: str | os.PathLike) -> SourceMesh:
    """Read a mesh file and return a cleaned, validated :class:`SourceMesh`.

    The file is read with ``trimesh.load_scene(path, process=False)`` so that
    trimesh merges nothing: vertices that differ in normal or uv stay apart
    (texture and normal seams survive). Every geometry of the scene is
    concatenated with its scene-graph transform applied.

    Args:
        path: the mesh file; its extension selects the format.

    Returns:
        The cleaned mesh; ``notes`` lists every repair.

    Raises:
        InputError: the file is missing, unreadable, of an unknown format,
            truncated, empty, holds only points or lines, or has NaN/infinite
            coordinates or texture coordinates. The message is one line and
            names the file.
    """
    path = Path(os.fspath(path))
    label = str(path)
    _check_is_file(path)
    file_type = _file_type_of(path)
    read_notes: list[str] = []
    scene = [_read_scene(path, file_type, read_notes)]      # a list, so that the conversion can let go of it
    try:
        source = _source_from_scene(scene, default_material=path.stem or "mesh", label=label)
        source.notes.extend(read_notes)
        if file_type == "obj":
            source.notes.extend(_undefined_obj_materials(path, len(source.materials)))
        return source
    except InputError:
        raise
    except Exception as exc:  # a trimesh object in a state we did not foresee
        raise InputError(
            f"{label}: could not convert the loaded {file_type.upper()} data "
            f"({_describe(exc)}); check the file in a mesh viewer and export it again"
        ) from None


_MATERIAL_LINE = re.compile(rb"^(usemtl|mtllib)[ \t]+([^\r\n]+)", re.MULTILINE)


def _undefined_obj_materials(path: Path, n_materials: int) -> list[str]:
    """A note when an OBJ's ``usemtl`` names materials its ``mtllib`` files do not define (or it has
    none): trimesh then reads those with texture coordinates as one unnamed material, with no seam
    between them, and names the others after its geometries; the note says which happened (from
    ``n_materials``, the materials read) and what to do. Read in blocks, as a line scan of the text."""
    used, libraries = set(), []
    rest = b""
    with open(path, "rb") as f:
        while True:
            block = f.read(1 << 24)
            text = rest + block
            cut = text.rfind(b"\n") + 1 if block else len(text)    # whole lines; the last block all of it
            for key, name in _MATERIAL_LINE.findall(text, 0, cut):
                (used.add if key == b"usemtl" else libraries.append)(name.strip())
            rest = text[cut:]
            if not block:
                break
    if len(used) < 2:
        return []                     # one material or none: nothing to tell apart
    defined = set()
    for name in libraries:
        try:
            text = (path.parent / name.decode("utf-8", "replace")).read_bytes()
        except (OSError, ValueError):     # missing, unreadable, or a name no path can hold (a NUL)
            continue
        defined.update(line.split(None, 1)[1].strip() for line in text.splitlines()
                       if line.startswith(b"newmtl") and len(line.split(None, 1)) == 2)
    missing = sorted(used - defined)
    if not missing:
        return []
    shown = ", ".join(m.decode("utf-8", "replace") for m in missing[:5]) + (", ..." if len(missing) > 5 else "")
    where = "its .mtl does not define them" if libraries else "it names no .mtl (mtllib)"
    what = ("takes them as one material, with no seam between them" if n_materials < len(used)
            else "names them after its geometries, not their usemtl names")
    return [f"{len(missing)} of its {len(used)} materials ({shown}) are not defined ({where}): the reader "
            f"{what}; put the .mtl file beside the .obj"]


def source_from_trimesh(mesh_or_scene, name: str = "mesh") -> SourceMesh:
    """Convert a ``trimesh.Trimesh`` or ``trimesh.Scene`` into a SourceMesh.

    The input is only read, never modified. Per-vertex attributes are taken
    as trimesh holds them:

    * normals: kept only when present in the mesh's cache
      (``'vertex_normals' in mesh._cache``), which is where trimesh's loaders
      put normals read from the file. trimesh computes normals lazily, so a
      mesh whose ``vertex_normals`` nobody read (and whose file had none)
      yields ``vertex_normal=None`` and the builder computes crease-angle
      normals. Note that reading ``mesh.vertex_normals`` yourself caches
      trimesh's smooth normals, which then count as present.
    * uv: ``mesh.visual.uv`` of a ``TextureVisuals``.
    * colour: ``ColorVisuals`` vertex colours; face colours are expanded to
      per-corner vertex colours; a glTF ``COLOR_0`` stored next to a texture
      (``visual.vertex_attributes['color']``) is used too.

    Args:
        mesh_or_scene: a ``trimesh.Trimesh`` or ``trimesh.Scene``.
        name: used in error messages and as the material name of a single
            geometry that carries no material name.

    Returns:
        The cleaned, validated mesh.

    Raises:
        InputError: no triangles, NaN/infinite coordinates or texture
            coordinates, or an object that is not a trimesh mesh or scene.
    """
    import trimesh

    if isinstance(mesh_or_scene, trimesh.Scene):
        scene = mesh_or_scene
    elif isinstance(mesh_or_scene, trimesh.parent.Geometry):
        # Wrapping in a Scene gives one code path for meshes, point clouds
        # and paths; the Scene references the geometry, it does not copy it.
        scene = trimesh.Scene()
        scene.add_geometry(mesh_or_scene, geom_name=name, node_name=name)
    else:
        raise InputError(
            f"{name}: expected a trimesh.Trimesh or trimesh.Scene, got "
            f"{type(mesh_or_scene).__name__}; load the mesh with trimesh first"
        )
    return _source_from_scene([scene], default_material=name, label=name)


# --------------------------------------------------------------------------
# reading the file
# --------------------------------------------------------------------------


def _check_is_file(path: Path) -> None:
    """Refuse a path that does not name a readable regular file."""
    if not path.exists():
        raise InputError(f"{path}: file not found; check the path and the working directory")
    if not path.is_file():
        raise InputError(f"{path}: is not a regular file; give the path of a mesh file")
    if not os.access(path, os.R_OK):
        raise InputError(f"{path}: permission denied; make the file readable")


def _file_type_of(path: Path) -> str:
    """Return trimesh's file type for ``path`` (its extension, lower case).

    Checked here rather than left to trimesh because trimesh's message for an
    unknown type quotes the whole path as the "type" when there is no dot.
    """
    import trimesh

    formats = sorted(trimesh.available_formats(), key=len, reverse=True)
    name = path.name.lower()
    for fmt in formats:  # longest first, so "tar.gz" wins over "gz"
        if name.endswith("." + fmt):
            return fmt
    mesh_formats = ", ".join(f".{f}" for f in ("obj", "ply", "glb", "gltf", "stl", "off"))
    suffix = path.suffix or "(no extension)"
    raise InputError(
        f"{path}: unknown mesh format {suffix}; give a file ending in one of {mesh_formats}"
    )


def _read_scene(path: Path, file_type: str, notes: list[str] | None = None):
    """Load ``path`` with trimesh into a ``trimesh.Scene``, merging nothing; an OBJ that trimesh
    would misread is rewritten first (:mod:`caveclod.builder.objtext`), saying so in ``notes``.

    Every exception trimesh raises becomes an InputError that names the file
    and the cause; warnings trimesh or numpy emit while parsing, and what
    trimesh logs, are silenced because they would reach the user as noise with
    no action to take (see :mod:`caveclod.builder.quiet`).
    """
    import trimesh

    from .gltfcodecs import UndecodedWatch, refuse_undecodable

    from .gltfquant import dequantized_gltf
    from .objtext import normalized_obj

    refuse_undecodable(path, file_type)           # compressed glTF geometry nothing here decodes
    rewritten = dequantized_gltf(path, file_type)  # quantized glTF attributes, which trimesh reads raw
    source, kind = (str(path), file_type) if rewritten is None else (io.BytesIO(rewritten), "glb")
    if file_type == "obj":
        try:
            text, obj_notes = normalized_obj(path)
        except OSError as exc:
            raise InputError(f"{path}: cannot read it ({exc.strerror or exc}); check that the file is readable") \
                from None
        if text is not None:
            source = io.BytesIO(text)                # its .mtl and textures still found beside ``path``
            if notes is not None:
                notes.extend(obj_notes)
    try:
        with quiet_reading("trimesh"), UndecodedWatch() as watch:
            if hasattr(trimesh, "load_scene"):  # trimesh >= 4.6
                scene = trimesh.load_scene(source, file_type=kind, process=False,
                                           resolver=trimesh.resolvers.FilePathResolver(str(path)))
            else:
                scene = trimesh.load(source, file_type=kind, process=False, force="scene",
                                     resolver=trimesh.resolvers.FilePathResolver(str(path)))
    except ImportError as exc:
        # trimesh imports optional modules lazily; for text formats it only
        # reaches for a charset detector when the bytes are not UTF-8, which
        # for a mesh file almost always means binary garbage or truncation.
        module = getattr(exc, "name", None) or "an optional module"
        raise InputError(
            f"{path}: could not read as {file_type.upper()}: the bytes do not parse "
            f"(trimesh then wanted {module}, which is not installed); the file is "
            f"probably truncated, corrupt or not really {file_type.upper()}"
        ) from None
    except Exception as exc:
        raise InputError(
            f"{path}: could not read as {file_type.upper()} ({_describe(exc)}); the file "
            f"is probably truncated, corrupt or not really {file_type.upper()}"
        ) from None
    watch.check(path)                             # geometry left as zeros by an extension that failed
    return scene


def _describe(exc: BaseException) -> str:
    """One-line, bounded description of an exception: ``Type: message``."""
    text = " ".join(str(exc).split())
    if len(text) > _MAX_CAUSE_CHARS:
        text = text[: _MAX_CAUSE_CHARS - 3] + "..."
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


# --------------------------------------------------------------------------
# scene -> concatenated arrays
# --------------------------------------------------------------------------


@dataclass
class _Part:
    """One placed geometry, attributes per vertex, transform already applied.

    positions: (n, 3) float64; faces: (m, 3) int64 into this part;
    normals: (n, 3) float64 or None; uv: (n, 2) float64 or None;
    colors: (n, 4) uint8 or None; material: the material name.
    """

    positions: np.ndarray
    faces: np.ndarray
    normals: np.ndarray | None
    uv: np.ndarray | None
    colors: np.ndarray | None
    material: str


@dataclass
class _Soup:
    """All parts concatenated, before welding.

    positions: (V, 3) float64; faces: (F, 3) int64; face_material: (F,) int32;
    normals: (V, 3) or None; uv: (V, 2) or None; colors: (V, 4) uint8 or None.
    """

    positions: np.ndarray
    faces: np.ndarray
    face_material: np.ndarray
    materials: list[str]
    normals: np.ndarray | None
    uv: np.ndarray | None
    colors: np.ndarray | None


def _source_from_scene(holder: list, default_material: str, label: str) -> SourceMesh:
    """Convert the trimesh Scene in ``holder`` (a one-item list): collect parts, concatenate, check, clean.

    The holder is emptied once the parts are made, and the parts once they
    are concatenated: read from a file, the scene (about 60 bytes a triangle
    for a binary PLY) and the parts (about 40) are then gone before the
    cleaning, which was the load's peak with them alive.
    """
    notes: list[str] = []
    parts = _collect_parts(holder[0], default_material, label, notes)
    holder.clear()
    soup = _concatenate(parts, notes)
    del parts
    _refuse_nonfinite_positions(soup, label)
    _refuse_far_positions(soup, label)
    _refuse_nonfinite_uv(soup, label)
    soup.normals = _unit_normals_or_none(soup.normals, notes)
    source = _clean(soup, label, notes)
    source.validate()
    return source


def _collect_parts(scene, default_material: str, label: str, notes: list[str]) -> list[_Part]:
    """One :class:`_Part` per scene-graph node that instances a triangle mesh.

    A geometry instanced by several nodes yields several parts (each with its
    own transform) sharing one material. Point clouds and paths are skipped;
    if nothing with triangles remains the mesh is refused.
    """
    import trimesh

    placed = _placed_geometries(scene, label)
    with_faces = {
        key
        for key, geom in scene.geometry.items()
        if isinstance(geom, trimesh.Trimesh) and len(geom.faces) > 0
    }
    # Material naming only falls back to geometry names when several
    # geometries would otherwise all get the same default name.
    several = len(with_faces) > 1
    parts: list[_Part] = []
    named: dict[str, dict] = {}               # name -> {material's content hash: the name it was given}
    for transform, geom_key in placed:
        if geom_key not in with_faces:
            continue
        geom = scene.geometry[geom_key]
        material = _distinct_name(_material_name(geom, geom_key if several else default_material),
                                  getattr(geom.visual, "material", None), named)
        parts.append(_part_from_trimesh(geom, transform, material, notes))
    if not parts:
        _refuse_no_triangles(scene, label)
    renamed = sorted(n for n, kinds in named.items() if len(kinds) > 1)
    if renamed:
        shown = ", ".join(repr(n) for n in renamed[:5]) + (", ..." if len(renamed) > 5 else "")
        k = len(renamed)
        notes.append(f"{k} material name{'s' if k > 1 else ''} ({shown}) {'are' if k > 1 else 'is'} shared by "
                     "materials that differ: kept apart as 'NAME #2', ... (glTF does not make names unique)")
    return parts


def _distinct_name(name: str, material, named: dict) -> str:
    """``name``, or ``name #k`` when materials that differ share it (glTF names need not be unique:
    two materials both called "Material", red and blue, became one material, the blue parts
    drawn with the red one's texture and no seam between them). Materials are told apart by
    trimesh's content hash (a material shared by several primitives is one object; equal
    copies hash alike)."""
    if material is None:
        return name
    kinds = named.setdefault(name, {})
    key = hash(material)
    if key not in kinds:
        kinds[key] = name if not kinds else f"{name} #{len(kinds) + 1}"
    return kinds[key]


def _placed_geometries(scene, label: str) -> list[tuple[np.ndarray, str]]:
    """(transform (4, 4) float64, geometry key) of every node that places a geometry.

    trimesh multiplies the scene graph's matrices here, with numpy warning
    about what overflows; a transform that is not finite is refused by name,
    since the geometry's own vertices may be fine.
    """
    with quiet_reading("trimesh"):
        placed = [(node, *scene.graph[node]) for node in scene.graph.nodes_geometry]
    out = []
    for node, transform, geom_key in placed:
        transform = np.asarray(transform, dtype=np.float64)
        if not np.isfinite(transform).all():
            raise InputError(
                f"{label}: the scene node {str(node)[:60]!r} has a NaN or infinite transform; fix its "
                f"matrix, translation, rotation or scale and export again"
            )
        out.append((transform, geom_key))
    return out


def _refuse_no_triangles(scene, label: str) -> None:
    """Raise the InputError for a scene with no triangles, saying what it holds."""
    others = [type(g).__name__ for g in scene.geometry.values()]
    if not others:
        raise InputError(
            f"{label}: contains no geometry (empty file?); give a mesh with at least one triangle"
        )
    kinds = ", ".join(sorted(set(others)))
    raise InputError(
        f"{label}: contains no triangles, only {kinds}; "
        f"export the surface as a triangle mesh"
    )


def _material_name(geom, fallback: str) -> str:
    """The material name trimesh gives ``geom``, else ``fallback``.

    OBJ files name materials after ``usemtl``; glTF uses its material names.
    Geometries whose materials share a name share one material id.
    """
    material = getattr(geom.visual, "material", None)
    name = getattr(material, "name", None)
    if isinstance(name, str) and name.strip():
        return name
    return fallback


def _part_from_trimesh(geom, transform: np.ndarray, material: str, notes: list[str]) -> _Part:
    """Extract arrays of one trimesh.Trimesh placed by ``transform`` (4, 4)."""
    positions = np.array(geom.vertices, dtype=np.float64)
    faces = np.array(geom.faces, dtype=np.int64)
    normals = _authored_normals(geom)
    uv = _uv_of(geom)
    colors, face_colors = _colors_of(geom)

    if faces.shape[1] != 3:
        faces, face_colors = _triangulate(faces, face_colors, notes)
    if face_colors is not None:
        positions, faces, normals, uv, colors = _expand_face_colors(
            positions, faces, normals, uv, face_colors, notes)

    positions, faces, normals = _apply_transform(transform, positions, faces, normals, notes)
    return _Part(positions, faces, normals, uv, colors, material)


def _authored_normals(geom) -> np.ndarray | None:
    """(n, 3) float64 normals the source provided, or None.

    trimesh stores normals it was given (by a loader or the constructor) in
    ``geom._cache['vertex_normals']`` and computes them only when
    ``geom.vertex_normals`` is read; so a normal present in the cache came
    from the source. Reading the property would compute smooth normals, so
    check the cache first.
    """
    if "vertex_normals" not in geom._cache:
        return None
    normals = np.asarray(geom._cache["vertex_normals"], dtype=np.float64)
    if normals.shape != (len(geom.vertices), 3):
        return None
    return normals


def _uv_of(geom) -> np.ndarray | None:
    """(n, 2) float64 texture coordinates of a TextureVisuals, or None."""
    visual = geom.visual
    if getattr(visual, "kind", None) != "texture":
        return None
    uv = getattr(visual, "uv", None)
    if uv is None:
        return None
    uv = np.asarray(uv, dtype=np.float64)
    if uv.ndim != 2 or uv.shape[0] != len(geom.vertices) or uv.shape[1] < 2:
        return None
    return uv[:, :2]


def _colors_of(geom) -> tuple[np.ndarray | None, np.ndarray | None]:
    """Vertex colours (n, 4) uint8 and face colours (m, 4) uint8, either None.

    ``visual.kind`` is checked before touching ``vertex_colors``: reading
    that property on a colourless ColorVisuals invents a default grey.
    """
    visual = geom.visual
    kind = getattr(visual, "kind", None)
    if kind == "vertex":
        return _as_rgba8(visual.vertex_colors), None
    if kind == "face":
        return None, _as_rgba8(visual.face_colors)
    if kind == "texture":
        # glTF COLOR_0 next to a texture lands in the visual's vertex_attributes; a PLY's or OBJ's
        # colours next to texture coordinates (photogrammetry exports have both) in the mesh's.
        for attributes in (getattr(visual, "vertex_attributes", None), getattr(geom, "vertex_attributes", None)):
            color = (attributes or {}).get("color")
            if color is not None and len(color) == len(geom.vertices):
                return _as_rgba8(color), None
    return None, None


def _as_rgba8(color) -> np.ndarray:
    """Any colour array (n, 3|4) (uint8, uint16, or float in [0, 1]) -> (n, 4) uint8."""
    color = np.asarray(color)
    if color.ndim != 2 or color.shape[1] not in (3, 4):
        raise ValueError(f"colour array of shape {color.shape}")
    if color.dtype == np.uint8:
        rgba = color
    elif color.dtype.kind == "f":
        rgba = np.round(np.clip(np.nan_to_num(color), 0.0, 1.0) * 255.0).astype(np.uint8)
    elif color.dtype == np.uint16:
        rgba = (color >> 8).astype(np.uint8)
    else:
        rgba = np.clip(color, 0, 255).astype(np.uint8)
    if rgba.shape[1] == 3:
        rgba = np.column_stack([rgba, np.full(len(rgba), 255, dtype=np.uint8)])
    return np.ascontiguousarray(rgba)


def _triangulate(faces: np.ndarray, face_colors, notes: list[str]):
    """Fan-split (m, k) polygons, k > 3, into (m * (k - 2), 3) triangles.

    trimesh normally triangulates while loading; this handles the rare mesh
    object built with wider faces. Face colours are repeated per triangle.
    """
    m, k = faces.shape
    if k < 3:
        raise InputError(f"faces have {k} corners; a mesh needs triangles")
    fans = np.arange(1, k - 1)
    tris = np.stack(
        [np.repeat(faces[:, :1], k - 2, axis=1), faces[:, fans], faces[:, fans + 1]], axis=2
    ).reshape(-1, 3)
    notes.append(f"triangulated {m} polygons with {k} corners into {len(tris)} triangles")
    if face_colors is not None:
        face_colors = np.repeat(face_colors, k - 2, axis=0)
    return tris, face_colors


def _expand_face_colors(positions, faces, normals, uv, face_colors, notes):
    """Turn per-face colours into per-vertex colours.

    Every face corner becomes its own vertex carrying its face's colour; the
    later attribute merge folds corners with equal attributes back together,
    so only real colour seams stay split.
    Returns positions (3m, 3), faces (m, 3), normals, uv, colors (3m, 4).
    """
    corner = faces.reshape(-1)
    notes.append(f"converted face colours of {len(faces)} faces to vertex colours")
    return (
        positions[corner],
        np.arange(len(corner), dtype=np.int64).reshape(-1, 3),
        None if normals is None else normals[corner],
        None if uv is None else uv[corner],
        np.repeat(face_colors, 3, axis=0),
    )


def _apply_transform(transform, positions, faces, normals, notes):
    """Place a part by its scene-graph transform (4, 4), finite.

    Normals go through the inverse transpose so they stay perpendicular under
    non-uniform scale (a singular transform, which flattens the part, leaves
    none: they are dropped, with a note); a mirroring transform (negative
    determinant) would turn the surface inside out, so the winding is
    reversed to keep faces counter-clockwise seen from outside.
    """
    if np.array_equal(transform, np.eye(4)):
        return positions, faces, normals
    linear = transform[:3, :3]
    # A huge transform makes infinite or far positions, which are refused
    # later with their count; numpy's overflow warnings would only be noise.
    with np.errstate(over="ignore", invalid="ignore"):
        positions = positions @ linear.T + transform[:3, 3]
        determinant = np.linalg.det(linear)
        if normals is not None and determinant != 0.0:
            # n' = M^-T n for column vectors, i.e. n' = n M^-1 for row vectors.
            normals = normals @ np.linalg.inv(linear)
        elif normals is not None:
            notes.append("ignored the vertex normals of a part its transform flattens (singular matrix)")
            normals = None
    if determinant < 0:
        faces = faces[:, ::-1].copy()
    return positions, faces, normals


def _concatenate(parts: list[_Part], notes: list[str]) -> _Soup:
    """Stack the parts into one soup; material ids by first appearance.

    An attribute only some parts have: normals are dropped (the builder then
    computes all of them consistently), uvs are filled with (0, 0) and
    colours with opaque white, each with a note.
    """
    materials: list[str] = []
    material_id: dict[str, int] = {}
    offsets = np.cumsum([0] + [len(p.positions) for p in parts])
    faces, face_material = [], []
    for part, offset in zip(parts, offsets):
        mid = material_id.setdefault(part.material, len(materials))
        if mid == len(materials):
            materials.append(part.material)
        faces.append(part.faces + offset)
        face_material.append(np.full(len(part.faces), mid, dtype=np.int32))

    have_normals = [p.normals is not None for p in parts]
    normals = None
    if all(have_normals):
        normals = np.concatenate([p.normals for p in parts])
    elif any(have_normals):
        notes.append(
            f"ignored vertex normals: only {sum(have_normals)} of {len(parts)} "
            f"geometries have them; all normals will be computed"
        )
    uv = _concatenate_or_fill(parts, "uv", 2, np.float64, 0.0,
                              "texture coordinates", "(0, 0)", notes)
    colors = _concatenate_or_fill(parts, "colors", 4, np.uint8, 255,
                                  "vertex colours", "white", notes)
    return _Soup(
        positions=np.concatenate([p.positions for p in parts]),
        faces=np.concatenate(faces),
        face_material=np.concatenate(face_material),
        materials=materials,
        normals=normals,
        uv=uv,
        colors=colors,
    )


def _concatenate_or_fill(parts, attr, width, dtype, fill, what, fill_name, notes):
    """Concatenate ``part.<attr>``; parts without it get ``fill`` (and a note)."""
    arrays = [getattr(p, attr) for p in parts]
    missing = [a is None for a in arrays]
    if all(missing):
        return None
    if any(missing):
        n_vertices = sum(len(p.positions) for p, m in zip(parts, missing) if m)
        notes.append(f"gave {n_vertices} vertices without {what} the value {fill_name}")
    return np.concatenate([
        np.full((len(p.positions), width), fill, dtype=dtype) if a is None else a.astype(dtype)
        for p, a in zip(parts, arrays)
    ])


# --------------------------------------------------------------------------
# checks and repairs of attribute values
# --------------------------------------------------------------------------


def _used_vertex_mask(n_vertices: int, faces: np.ndarray) -> np.ndarray:
    """(n_vertices,) bool: True where some face refers to the vertex."""
    used = np.zeros(n_vertices, dtype=bool)
    used[faces.reshape(-1)] = True
    return used


def _refuse_nonfinite_positions(soup: _Soup, label: str) -> None:
    """Refuse NaN/inf coordinates on vertices a face uses.

    Dropping them would silently cut holes, so the user must fix the file.
    Vertices no face uses are dropped later anyway, whatever they hold.
    """
    bad = ~np.isfinite(soup.positions).all(axis=1)
    bad &= _used_vertex_mask(len(soup.positions), soup.faces)
    n_bad = int(bad.sum())
    if n_bad:
        raise InputError(
            f"{label}: {n_bad} vertices have NaN or infinite coordinates; "
            f"fix or delete them in the modelling tool and export again"
        )


def _refuse_far_positions(soup: _Soup, label: str) -> None:
    """Refuse coordinates beyond +-MAX_COORDINATE on vertices a face uses.

    Such a mesh would be stored with infinite positions (beyond float32's
    3.4e38) or bounds whose squares overflow float32 (see MAX_COORDINATE);
    only the user knows which scale was meant. Call after the NaN check.
    """
    bad = out_of_range_rows(soup.positions) & _used_vertex_mask(len(soup.positions), soup.faces)
    n_bad = int(bad.sum())
    if n_bad:
        largest = float(np.abs(soup.positions[bad]).max())
        raise InputError(
            f"{label}: {n_bad} vertices have coordinates beyond +-{MAX_COORDINATE:.2g} (the largest is "
            f"{largest:.3g}), too far for the float32 the .cvc stores positions in; scale the mesh down "
            f"(export it in larger units) or delete the stray vertices"
        )


def _refuse_nonfinite_uv(soup: _Soup, label: str) -> None:
    """Refuse NaN/inf texture coordinates, and those beyond float32's range
    (they would be stored as infinities): no safe value to put instead."""
    if soup.uv is None:
        return
    used = _used_vertex_mask(len(soup.uv), soup.faces)
    n_nan = int((~np.isfinite(soup.uv).all(axis=1) & used).sum())
    if n_nan:
        raise InputError(
            f"{label}: {n_nan} vertices have NaN or infinite texture coordinates; "
            f"fix the UV map and export again"
        )
    n_far = int((out_of_range_rows(soup.uv, FLOAT32_MAX) & used).sum())
    if n_far:
        raise InputError(
            f"{label}: {n_far} vertices have texture coordinates beyond +-{FLOAT32_MAX:.3g}, float32's "
            f"range; fix the UV map and export again"
        )


def _unit_normals_or_none(normals: np.ndarray | None, notes: list[str]) -> np.ndarray | None:
    """(V, 3) float32 unit normals, or None when any normal is unusable.

    A NaN/inf or zero-length normal leaves no direction to shade with; one
    bad normal discards the whole array, because mixing file normals with
    computed ones would show seams where the two methods disagree.
    """
    if normals is None:
        return None
    finite = np.isfinite(normals).all(axis=1)
    if not finite.all():
        notes.append(
            f"ignored vertex normals: {int((~finite).sum())} are NaN or infinite; "
            f"all normals will be computed"
        )
        return None
    # Squaring 1e200 overflows and squaring 1e-200 underflows: scale each
    # row by its largest component first, so its length is in [1, sqrt(3)]
    # (0 for a zero row).
    largest = np.abs(normals).max(axis=1)
    scaled = normals / np.where(largest > 0.0, largest, 1.0)[:, None]
    scaled_length = np.sqrt(np.einsum("ij,ij->i", scaled, scaled))
    with np.errstate(over="ignore"):  # an infinite length is just "not unit"
        length = largest * scaled_length
    zero = length < _MIN_NORMAL_LENGTH
    if zero.any():
        notes.append(
            f"ignored vertex normals: {int(zero.sum())} have zero length; "
            f"all normals will be computed"
        )
        return None
    off_unit = int((np.abs(length - 1.0) > _UNIT_TOLERANCE).sum())
    if off_unit:
        notes.append(f"renormalised {off_unit} vertex normals that were not unit length")
    return (scaled / scaled_length[:, None]).astype(np.float32)


# --------------------------------------------------------------------------
# welding and cleaning
# --------------------------------------------------------------------------


def _clean(soup: _Soup, label: str, notes: list[str]) -> SourceMesh:
    """Weld, merge, drop degenerate/duplicate faces and unused elements."""
    positions, vertex_pos_in, first_pos_in = _weld_positions(soup.positions)
    normals = _positive_zero(soup.normals)
    uv = _positive_zero(None if soup.uv is None else soup.uv.astype(np.float32))
    colors = soup.colors

    # Merge vertices whose whole attribute row is bitwise equal. With no
    # attribute besides the position, vertices are positions (skip a sort).
    if normals is None and uv is None and colors is None:
        vertex_of_input, first_input = vertex_pos_in, first_pos_in
    else:
        rows = _attribute_rows(vertex_pos_in, normals, uv, colors)
        vertex_of_input, first_input = _group_equal_rows(rows)
    vertex_position = vertex_pos_in[first_input]
    faces = vertex_of_input[soup.faces]
    face_material = soup.face_material

    keep = _nondegenerate_faces(vertex_position[faces])
    n_degenerate = int((~keep).sum())
    if n_degenerate:
        notes.append(f"dropped {n_degenerate} degenerate faces "
                     f"(a position used twice after exact welding)")
    if not keep.any():
        raise InputError(
            f"{label}: every face is degenerate (uses one position twice); "
            f"give a mesh with at least one proper triangle"
        )

    kept_index = np.flatnonzero(keep)
    first_copy = _first_of_duplicate_faces(vertex_position[faces[kept_index]],
                                           face_material[kept_index])
    n_duplicate = int((~first_copy).sum())
    if n_duplicate:
        notes.append(f"dropped {n_duplicate} duplicate faces "
                     f"(same positions in the same order and same material)")
    kept_index = kept_index[first_copy]

    faces = faces[kept_index]
    face_material = face_material[kept_index]
    _note_unused(soup, kept_index, len(positions), vertex_position[faces], notes)

    vertex_keep = _used_vertex_mask(len(vertex_position), faces)
    faces = _renumber(vertex_keep)[faces]
    vertex_position = vertex_position[vertex_keep]
    position_keep = _used_vertex_mask(len(positions), vertex_position)
    vertex_position = _renumber(position_keep)[vertex_position]
    positions = positions[position_keep]

    def pick(arr):
        return None if arr is None else np.ascontiguousarray(arr[first_input][vertex_keep])

    return SourceMesh(
        positions=positions,
        vertex_position=vertex_position.astype(np.int64),
        faces=faces.astype(np.int64),
        face_material=face_material.astype(np.int32),
        materials=list(soup.materials),
        vertex_normal=pick(normals),
        vertex_uv=pick(uv),
        vertex_color=pick(colors),
        notes=notes,
    )


def _weld_positions(positions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Weld bitwise-equal coordinates.

    Args:
        positions: (V, 3) float64 coordinates of each input vertex.

    Returns:
        unique (e, 3) float64 positions in order of first appearance,
        (V,) int64 position id of each input vertex, and
        (e,) int64 first input vertex of each position.
    """
    coords = _positive_zero(np.ascontiguousarray(positions, dtype=np.float64))
    position_of_input, first = _group_equal_rows(coords)
    return coords[first], position_of_input, first


def _positive_zero(a: np.ndarray | None) -> np.ndarray | None:
    """Replace -0.0 by +0.0 so that bitwise equality matches numeric equality."""
    if a is None:
        return None
    return a + a.dtype.type(0)  # IEEE: -0.0 + 0.0 == +0.0, every other value unchanged


def _attribute_rows(position_id, normals, uv, colors) -> np.ndarray:
    """(V, w) uint8: each vertex's attributes as raw bytes, for bitwise merging."""
    columns = [position_id.astype(np.int64)[:, None]]
    for arr in (normals, uv, colors):
        if arr is not None:
            columns.append(np.ascontiguousarray(arr))
    n = len(position_id)
    return np.concatenate([c.view(np.uint8).reshape(n, -1) for c in columns], axis=1)


def _nondegenerate_faces(face_positions: np.ndarray) -> np.ndarray:
    """(p,) bool: True where a face's three position ids are distinct.

    Zero-area faces with distinct positions (slivers) are legal and kept.
    """
    a, b, c = face_positions.T
    return (a != b) & (b != c) & (c != a)


def _first_of_duplicate_faces(face_positions: np.ndarray, face_material: np.ndarray) -> np.ndarray:
    """(p,) bool: False for a face repeating an earlier one.

    A repeat has the same positions in the same cyclic order and the same
    material. Rotating each face so its smallest position comes first makes
    the three rotations of a face compare equal, while the reversed winding
    (double-sided geometry) stays different and is kept.

    One 64-bit hash a face, sorted; faces with equal hashes are compared
    exactly (:func:`caveclod.kernels.duplicates.keep_first_faces`). 17 bytes a face where rows of the
    rotated faces, their words and the grouping's arrays took about 160 (the
    loading's peak).
    """
    from ..kernels.duplicates import keep_first_faces, rotated_face_hashes
    fp = np.ascontiguousarray(face_positions, dtype=np.int64)
    material = np.ascontiguousarray(face_material, dtype=np.int64)
    key = rotated_face_hashes(fp, material)
    return keep_first_faces(fp, material, key, np.argsort(key, kind="stable"))


def _note_unused(soup: _Soup, kept_faces, n_positions, kept_face_positions, notes) -> None:
    """Note how many input vertices and welded positions no kept face uses."""
    used_inputs = _used_vertex_mask(len(soup.positions), soup.faces[kept_faces])
    n_unused_vertices = len(used_inputs) - int(used_inputs.sum())
    n_unused_positions = n_positions - int(_used_vertex_mask(n_positions, kept_face_positions).sum())
    if n_unused_vertices or n_unused_positions:
        notes.append(
            f"dropped {n_unused_vertices} vertices ({n_unused_positions} positions) that no face uses"
        )


def _renumber(keep: np.ndarray) -> np.ndarray:
    """(n,) int64 new index of each kept element (order kept); -1 for dropped."""
    new = np.full(len(keep), -1, dtype=np.int64)
    new[keep] = np.arange(int(keep.sum()), dtype=np.int64)
    return new


# --------------------------------------------------------------------------
# grouping equal rows fast
# --------------------------------------------------------------------------

_HASH_SEED = np.uint64(0x243F6A8885A308D3)
_HASH_MULTIPLIER = np.uint64(0x9E3779B97F4A7C15)


def _as_words(rows: np.ndarray) -> np.ndarray:
    """(n, w) uint64 view of the raw bytes of each row, zero-padded to 8 bytes."""
    rows = np.ascontiguousarray(rows)
    n = len(rows)
    raw = rows.view(np.uint8).reshape(n, -1)
    pad = (-raw.shape[1]) % 8
    if pad:
        raw = np.concatenate([raw, np.zeros((n, pad), dtype=np.uint8)], axis=1)
    return np.ascontiguousarray(raw).view(np.uint64)


def _hash_words(words: np.ndarray) -> np.ndarray:
    """(n,) uint64 hash of each row of (n, w) uint64 (multiply-xorshift)."""
    h = np.full(len(words), _HASH_SEED, dtype=np.uint64)
    shift = np.uint64(29)
    for j in range(words.shape[1]):  # loop over columns (a handful), not rows
        h ^= words[:, j]
        h *= _HASH_MULTIPLIER  # wraps modulo 2**64 by design
        h ^= h >> shift
    return h


def _group_equal_rows(rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Group rows whose bytes are identical.

    Sorting one 64-bit hash per row is several times faster than
    ``np.unique(rows, axis=0)``; the result is then verified row by row and,
    in the astronomically rare case of a hash collision, recomputed by an
    exact (stable) lexicographic sort.

    Args:
        rows: (n, ...) array of any fixed-size dtype.

    Returns:
        group: (n,) int64 group id of each row, groups numbered in order of
            first appearance (so an already clean mesh keeps its numbering);
        first: (g,) int64 index of the first row of each group.
    """
    n = len(rows)
    if n == 0:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    words = _as_words(rows)
    if words.shape[1] == 1:
        return _group_sorted(words[:, 0], np.argsort(words[:, 0]), None)
    key = _hash_words(words)
    group, first = _group_sorted(key, np.argsort(key), None)
    if np.array_equal(words[first[group]], words):
        return group, first
    order = np.lexsort(words.T[::-1])  # exact fallback; lexsort is stable
    return _group_sorted(None, order, words)


def _group_sorted(key, order, words) -> tuple[np.ndarray, np.ndarray]:
    """Shared tail of :func:`_group_equal_rows` given a sort order.

    Equal rows are adjacent in ``order`` (any sort, stable or not); compares
    ``key`` (n,) if given, else the full ``words`` (n, w).
    """
    n = len(order)
    starts = np.empty(n, dtype=bool)
    starts[0] = True
    if key is not None:
        sorted_key = key[order]
        starts[1:] = sorted_key[1:] != sorted_key[:-1]
    else:
        sorted_words = words[order]
        starts[1:] = (sorted_words[1:] != sorted_words[:-1]).any(axis=1)
    group_in_sorted = np.cumsum(starts) - 1
    # numpy's default sort is not stable (but is the fastest), so the first
    # row of a group is the smallest index within its run of the order.
    first_by_key = np.minimum.reduceat(order, np.flatnonzero(starts))
    # Renumber groups by first appearance: counting first rows up to each
    # first row gives its rank, in O(n) instead of another sort.
    is_first = np.zeros(n, dtype=bool)
    is_first[first_by_key] = True
    rank = (np.cumsum(is_first) - 1)[first_by_key]
    group = np.empty(n, dtype=np.int64)
    group[order] = rank[group_in_sorted]
    return group, np.flatnonzero(is_first).astype(np.int64)
