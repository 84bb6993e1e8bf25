"""The static CAVECLOD mesh and its memory-mapped ``.cvc`` file.

One static mesh is shared, read-only, by every camera (paper section 3.4).
Node ids: ``0 .. e-1`` are the leaves, one per position (leaf ``x`` sits at
position ``x``); ``e .. e+m-1`` are the nodes made by the build's collapses,
and arrays prefixed ``node_`` other than ``node_parent`` are indexed by
``node - e``.

File layout (version 2, little-endian)::

    b"CAVECLOD" | uint32 version | uint32 header length | header JSON | pad
    arrays, each aligned to 64 bytes at the offset the header gives
    attachments (optional), each aligned likewise

Attachments are named byte strings with JSON metadata that the build
derives from the arrays so that a server need not at start (the packed
vertex downloads, :func:`caveclod.vertexpack.attach_packed`). A reader
ignores names it does not know, so files with or without them load alike.
Arrays of :data:`OPTIONAL_ARRAYS` may be absent likewise: a file from before
one loads without what it adds (no ``node_ring``: the refinement's ring test
is off), and a reader that does not know one ignores it. The content hash
(the mesh's identity) covers :data:`ARRAYS`; the optional arrays have a hash
of their own (``optional_hash`` in the header), which :meth:`StaticMesh.verify`
checks too, so a reader from before them still verifies a newer file.

Loading reads only the header; arrays are ``np.memmap`` views, so a server
can open a multi-gigabyte mesh at once and share its pages between processes.
"""

from __future__ import annotations

import contextlib
import hashlib
import itertools
import json
import math
import os
import stat
import struct
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .errors import FileFormatError, InputError, MeshDamagedError

MAGIC = b"CAVECLOD"
VERSION = 2
ALIGN = 64

# name: (dtype, trailing shape) for every array; counts come from the data.
ARRAYS = {
    "vertex_positions": ("<f4", (3,)),   # (d, 3) the vertex buffer ...
    "vertex_normals": ("<f4", (3,)),     # (d, 3)
    "vertex_uvs": ("<f4", (2,)),         # (d, 2)
    "vertex_colors": ("u1", (4,)),       # (d, 4) RGBA; (0, 4) when absent
    "vertex_sgid": ("<u2", ()),          # (d,) surface group id of each entry
    "vertex_surface": ("<u2", ()),       # (d,) material of each entry
    "pos_vstart": ("<i4", ()),           # (e+1,) CSR: vertices of position x
    "position_class": ("u1", ()),        # (e,) FREE / SHARP / RIGID
    "face_material": ("<u2", ()),        # (p,) the paper's surface identifier
    "face_sgid": ("<u2", ()),            # (p,) surface group id
    "face_creator": ("<i4", ()),         # (p,) node whose split makes it, -1: base
    "face_rotation": ("u1", ()),         # (p,) where the split's first corner goes (source order)
    "node_parent": ("<i4", ()),          # (n,) -1 for roots
    "node_links": ("<i4", (8,)),         # (m, 8) t, u, fl, fr, fl_u, fl_t, fr_u, fr_t
    "node_position": ("<i4", ()),        # (m,) = position of t
    "node_bound": ("<f4", (5,)),         # (m, 5) sphere centre, radius; error bound
    "node_cone": ("<f4", (4,)),          # (m, 4) normal cone axis, half-angle
    "base_faces": ("<i4", ()),           # (k,) faces of the coarsest mesh
    "base_face_nodes": ("<i4", (3,)),    # (k, 3) their nodes
    "base_face_nbrs": ("<i4", (3,)),     # (k, 3) their neighbour faces
}
OPTIONAL_ARRAYS = {
    "node_ring": ("<f4", (2,)),          # (m, 2) ring bound: reach, error (files from before it have none)
    # DERIVED_ARRAYS: what a process would otherwise derive from the arrays above for its first camera.
    "vertex_position": ("<i4", ()),      # (d,) position of each vertex-buffer entry: pos_vstart's inverse
    "material_faces": ("<i8", (2,)),     # (materials, 2) faces of each material: the full mesh's, the base mesh's
    "part_sphere": ("<f8", (4,)),        # (parts, 4) and the four below: caveclod.refine.parts.Parts
    "part_root_start": ("<i8", ()),      # (parts + 1,)
    "part_roots": ("<i4", ()),           # (roots,)
    "part_face_start": ("<i8", ()),      # (parts + 1,)
    "part_faces": ("<i4", ()),           # (base faces,)
}
DERIVED_ARRAYS = ("vertex_position", "material_faces", "part_sphere", "part_root_start", "part_roots",
                  "part_face_start", "part_faces")
"""Optional arrays that the other arrays determine: derived once per process when a file lacks
them (files from before 2026-11-29), stored by the build so that a server's start does not grow
with the mesh (1.2 s of a 47M-triangle terrain's first camera) and their pages are mapped and
shared by every server process instead of held by each. :mod:`caveclod.meshcheck` compares them
with a fresh derivation; :attr:`StaticMesh.nbytes` leaves them out (``derived_bytes``)."""
DECLARED = {**ARRAYS, **OPTIONAL_ARRAYS}
VERTEX_BUFFER = ("vertex_positions", "vertex_normals", "vertex_uvs", "vertex_colors")
COUNT_BLOCK = 1 << 20        # faces per pass of material_face_counts


@dataclass
class Attachment:
    """A named byte string stored beside the arrays (module doc): ``meta`` (JSON
    object) says what it is, ``data`` (nbytes,) uint8 holds it (mapped when loaded)."""

    meta: dict
    data: np.ndarray


@dataclass
class StaticMesh:
    """A built CAVECLOD hierarchy; see the module docstring for node ids.

    Attributes are the arrays of :data:`ARRAYS` (numpy arrays or memmaps)
    plus ``materials`` (names), ``info`` (build report) and ``path``;
    ``damaged`` is set (what was found, a short phrase) once a camera found
    the mesh damaged (:meth:`mark_damaged`): no new camera is made of it then.
    """

    arrays: dict
    materials: list
    info: dict = field(default_factory=dict)
    path: str | None = None
    content_hash: str = ""
    vertex_buffer_hash: str = ""
    optional_hash: str | None = None       # of the OPTIONAL_ARRAYS present ("" for none); None: compute it
    damaged: str = ""
    attachments: dict = field(default_factory=dict)     # name -> Attachment

    def __post_init__(self):
        missing = set(ARRAYS) - set(self.arrays)
        if missing:
            raise FileFormatError(f"static mesh lacks arrays {sorted(missing)}")
        if not self.content_hash:
            self.content_hash, self.vertex_buffer_hash = _hashes(self.arrays)
        if self.optional_hash is None:
            self.optional_hash = _optional_hash(self.arrays)

    def __getattr__(self, name):
        arrays = self.__dict__.get("arrays")
        if arrays is not None and name in arrays:
            return arrays[name]
        raise AttributeError(name)

    # node_links packs what a split or collapse reads into one 32-byte row
    # (children, the faces fl/fr it makes, the four neighbours it needs):
    # the refinement tests it for thousands of nodes a frame.
    @property
    def node_children(self) -> np.ndarray:
        """(m, 2) stationary child t and floating child u of each internal node."""
        return self.arrays["node_links"][:, 0:2]

    @property
    def node_faces(self) -> np.ndarray:
        """(m, 2) faces fl, fr that the node's split creates (-1 if absent)."""
        return self.arrays["node_links"][:, 2:4]

    @property
    def node_fn(self) -> np.ndarray:
        """(m, 4) neighbour faces the split requires: fl_u, fl_t, fr_u, fr_t."""
        return self.arrays["node_links"][:, 4:8]

    @property
    def node_sphere(self) -> np.ndarray:
        """(m, 4) bounding sphere (centre, radius) of each internal node's subtree."""
        return self.arrays["node_bound"][:, :4]

    @property
    def node_error(self) -> np.ndarray:
        """(m,) object-space error bound of each internal node.

        Stored beside the sphere (one row of ``node_bound``) because the
        refinement reads both for every active node each frame.
        """
        return self.arrays["node_bound"][:, 4]

    # -- counts -----------------------------------------------------------
    @property
    def n_positions(self) -> int:
        return len(self.arrays["pos_vstart"]) - 1

    @property
    def n_vertices(self) -> int:
        return len(self.arrays["vertex_positions"])

    @property
    def n_faces(self) -> int:
        return len(self.arrays["face_material"])

    @property
    def n_nodes(self) -> int:
        return len(self.arrays["node_parent"])

    @property
    def n_internal(self) -> int:
        return len(self.arrays["node_position"])

    @property
    def n_sgids(self) -> int:
        return int(self.arrays["vertex_sgid"].max()) + 1 if self.n_vertices else 0

    @property
    def n_materials(self) -> int:
        return len(self.materials)

    @property
    def nbytes(self) -> int:
        """Bytes of the hierarchy's static arrays (what every camera shares), not counting the
        :data:`DERIVED_ARRAYS` (:attr:`derived_bytes`)."""
        return int(sum(a.nbytes for name, a in self.arrays.items() if name not in DERIVED_ARRAYS))

    @property
    def derived_bytes(self) -> int:
        """Bytes of the :data:`DERIVED_ARRAYS` the mesh holds (0 for a file without them)."""
        return int(sum(a.nbytes for name, a in self.arrays.items() if name in DERIVED_ARRAYS))

    @property
    def equation1_bytes(self) -> int:
        """The paper's Equation 1 static term 44n + 12p + 32d + 2se."""
        return (44 * self.n_nodes + 12 * self.n_faces + 32 * self.n_vertices
                + 2 * self.n_sgids * self.n_positions)

    @property
    def positions(self) -> np.ndarray:
        """(e, 3) float32 position of each node position id."""
        return self.arrays["vertex_positions"][self.arrays["pos_vstart"][:-1]]

    @property
    def vertex_position_ids(self) -> np.ndarray:
        """(d,) int32 position id of each vertex-buffer entry (inverse of the
        CSR ``pos_vstart``), read-only: the file's ``vertex_position``, else
        derived once per process (:func:`derive_vertex_positions`)."""
        ids = self.__dict__.get("_vertex_position_ids")
        if ids is None:
            stored = self.arrays.get("vertex_position")
            ids = _read_only(stored) if stored is not None else derive_vertex_positions(self)
            self.__dict__["_vertex_position_ids"] = ids
        return ids

    @property
    def origin(self) -> tuple[float, float, float] | None:
        """The point a build with ``--origin`` subtracted from every position (add it back to place
        the mesh in the world), or None."""
        origin = self.info.get("origin")
        return None if origin is None else (float(origin[0]), float(origin[1]), float(origin[2]))

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """(lo, hi) float64 (3,) corners of the axis-aligned bounding box of the positions.

        Computed once (every new camera asks; the structural check at load
        computes it first), returned as copies."""
        box = self.__dict__.get("_bounds")
        if box is None:
            from .meshcheck import column_ranges
            box = column_ranges(np.asarray(self.arrays["vertex_positions"]))
            self.__dict__["_bounds"] = box
        return box[0].copy(), box[1].copy()

    def material_face_counts(self) -> tuple[np.ndarray, np.ndarray]:
        """((m,) faces of each material in the full mesh, (m,) in the base mesh), int64: the file's
        ``material_faces``, else counted once per process (:func:`count_material_faces`)."""
        counts = self.__dict__.get("_material_face_counts")
        if counts is None:
            stored = self.arrays.get("material_faces")
            table = np.asarray(stored) if stored is not None else count_material_faces(self)
            m = max(self.n_materials, len(table))      # names without faces count none
            counts = tuple(np.pad(table[:, j], (0, m - len(table))).astype(np.int64) for j in (0, 1))
            self.__dict__["_material_face_counts"] = counts
        return counts

    def parts(self):
        """The connected parts of the base mesh (:class:`caveclod.refine.parts.Parts`): the file's
        ``part_*`` arrays, else derived once per process (:func:`caveclod.refine.parts.mesh_parts`)."""
        parts = self.__dict__.get("_parts")
        if parts is None:
            from .refine.parts import Parts, mesh_parts
            if all(name in self.arrays for name in PART_ARRAYS):
                parts = Parts(*(_read_only(self.arrays[name]) for name in PART_ARRAYS))
            else:
                parts = mesh_parts(self)
            self.__dict__["_parts"] = parts
        return parts

    def store_derived(self) -> None:
        """Add the :data:`DERIVED_ARRAYS` to the arrays (derived afresh), so that a file saved
        from this mesh carries them; the build does this."""
        self.arrays.update(derived_arrays(self))
        self.optional_hash = _optional_hash(self.arrays)
        for cached in ("_vertex_position_ids", "_material_face_counts", "_parts"):
            self.__dict__.pop(cached, None)

    def position_tops(self) -> np.ndarray:
        """(e,) int32 the last node at each position, read-only; computed once.

        The nodes at a position form one chain of stationary children (node
        ids grow up it); its last node's parent is the collapse that took the
        position away (none: a root). The strict bound reads whether a
        position was gone before a node was made from it
        (:mod:`caveclod.kernels.refine`, "the strict bound").
        """
        tops = self.__dict__.get("_position_tops")
        if tops is None:
            e = self.n_positions
            npos = np.asarray(self.arrays["node_position"])
            tops = np.arange(e, dtype=np.int32)
            np.maximum.at(tops, npos, np.arange(e, e + len(npos), dtype=np.int32))
            tops.setflags(write=False)      # like a loaded file's maps: one compiled variant of the kernel
            self.__dict__["_position_tops"] = tops
        return tops

    def node_positions(self, nodes: np.ndarray) -> np.ndarray:
        """(k,) position ids of ``nodes`` (leaves or internal)."""
        nodes = np.asarray(nodes)
        e = self.n_positions
        out = nodes.copy()
        internal = nodes >= e
        out[internal] = self.arrays["node_position"][nodes[internal] - e]
        return out

    def lookup_vertices(self, sgid: np.ndarray, pos: np.ndarray) -> np.ndarray:
        """Vertex-buffer index for each (surface group id, position) pair.

        The paper's D3Dindex array. Raises ``KeyError`` when a pair has no
        vertex, which a correct hierarchy never asks for.
        """
        start = self.arrays["pos_vstart"]
        vsg = self.arrays["vertex_sgid"]
        sgid, pos = np.asarray(sgid), np.asarray(pos)
        out = np.full(sgid.shape, -1, np.int64)
        lo, hi = start[pos], start[pos + 1]
        width = int((hi - lo).max(initial=0))
        for j in range(width):
            idx = np.minimum(lo + j, len(vsg) - 1)
            hit = (lo + j < hi) & (vsg[idx] == sgid)
            out[hit] = idx[hit]
        if (out < 0).any():
            raise KeyError("a (surface group id, position) pair has no vertex")
        return out

    def class_tally(self) -> dict:
        from .builder.surfaces import CLASS_NAMES
        counts = np.bincount(np.asarray(self.arrays["position_class"]), minlength=3)
        return {name: int(c) for name, c in zip(CLASS_NAMES, counts)}

    def summary(self) -> dict:
        """Counts for ``caveclod build/inspect --json``."""
        out = {
            "nodes": self.n_nodes,
            "internal_nodes": self.n_internal,
            "faces": self.n_faces,
            "vertices": self.n_vertices,
            "positions": self.n_positions,
            "surface_group_ids": self.n_sgids,
            "materials": self.n_materials,
            "base_faces": len(self.arrays["base_faces"]),
            "static_bytes": self.nbytes,
            "derived_bytes": self.derived_bytes,
            "equation1_static_bytes": self.equation1_bytes,
            "content_hash": self.content_hash,
            "vertex_buffer_hash": self.vertex_buffer_hash,
            "optional_hash": self.optional_hash,
            "attachments": {name: int(a.data.nbytes) for name, a in sorted(self.attachments.items())},
        }
        out.update({k: v for k, v in self.info.items() if k not in out})
        return out

    def new_camera(self, **options):
        """A fresh per-camera refinement state showing the base mesh.

        ``options``: :class:`~caveclod.refine.camera.CameraState`'s
        (``max_ops``, ``max_faces``, ``expiries``, ``strict_bound``).
        """
        from .refine.camera import CameraState
        if self.damaged:
            raise self.mark_damaged(self.damaged)
        return CameraState(self, **options)

    def mark_damaged(self, what: str) -> MeshDamagedError:
        """Record that a camera found this mesh damaged (``what``: how, a short
        phrase; the first one found is kept) and return the error to raise: one
        line naming the file and saying to rebuild it."""
        self.damaged = self.damaged or what
        return MeshDamagedError(str(damaged_error(self.path or "the static mesh", what)))

    # -- file -------------------------------------------------------------
    def save(self, path: str | os.PathLike) -> None:
        """Write the versioned ``.cvc`` file (atomically: temp file + rename).

        The temp file is a new name beside ``path`` (``.NAME.XXXXXXXX.tmp``, NAME cut to 200 bytes:
        ``NAME.tmp`` refused names of 252 to 255 bytes) and is removed on any
        failure, an interrupt included (a killed build left a partial NAME.tmp, up to hundreds of
        MB, and a full disk stayed full). ``path`` must not be anything but a regular file: run as
        root, renaming over /dev/null or a FIFO replaced it with the mesh."""
        path = Path(path)
        refuse_output_path(path)
        table, offset = {}, 0
        for name in _present(self.arrays):
            a = self.arrays[name]
            table[name] = {"dtype": DECLARED[name][0], "shape": list(a.shape), "offset": offset,
                           "nbytes": int(a.nbytes)}
            offset += _aligned(a.nbytes)
        attached = {}
        for name, att in sorted(self.attachments.items()):
            attached[name] = {"offset": offset, "nbytes": int(att.data.nbytes), "meta": att.meta}
            offset += _aligned(att.data.nbytes)
        header = {"format": "caveclod-static", "version": VERSION, "materials": list(self.materials),
                  "info": self.info, "content_hash": self.content_hash,
                  "vertex_buffer_hash": self.vertex_buffer_hash, "optional_hash": self.optional_hash,
                  "arrays": table, "attachments": attached}
        blob = json.dumps(header, sort_keys=True).encode()
        data_start = _aligned(len(MAGIC) + 8 + len(blob))
        stem = path.name
        while len(os.fsencode(stem)) > 200:     # bytes, not characters: 'é' * 121 + '.cvc' is 246 bytes
            stem = stem[:-1]
        fd, tmp = tempfile.mkstemp(prefix="." + stem + ".", suffix=".tmp", dir=path.parent)
        try:
            with os.fdopen(fd, "wb") as fh:
                fh.write(MAGIC + struct.pack("<II", VERSION, len(blob)) + blob)
                fh.write(b"\0" * (data_start - fh.tell()))
                for name in table:
                    a = _as_declared(name, self.arrays[name])
                    fh.write(a.tobytes())
                    fh.write(b"\0" * (_aligned(a.nbytes) - a.nbytes))
                for name in attached:
                    data = np.ascontiguousarray(self.attachments[name].data).reshape(-1).view(np.uint8)
                    fh.write(data)
                    fh.write(b"\0" * (_aligned(data.nbytes) - data.nbytes))
            os.chmod(tmp, 0o666 & ~_umask())      # as open() would have made it (mkstemp makes 0600)
            os.replace(tmp, path)
        except BaseException:
            with contextlib.suppress(OSError):
                os.unlink(tmp)
            raise
        self.path = str(path)

    def verify(self) -> None:
        """Re-hash every array and check every stored attachment's CRC-32s (reads the whole file);
        raise if anything changed. (Attachments were not checked: a flipped byte in a stored packed
        download passed ``inspect --verify``, which serve then refused.)"""
        import zlib
        from .vertexpack import stored_meta_crc32
        content, _ = _hashes(self.arrays)
        if content != self.content_hash or _optional_hash(self.arrays) != self.optional_hash:
            raise FileFormatError(f"{self.path}: content hash mismatch; the file is corrupt, rebuild it")
        for name, att in sorted(self.attachments.items()):
            meta = att.meta if isinstance(att.meta, dict) else {}
            damaged = ("meta_crc32" in meta and meta["meta_crc32"] != stored_meta_crc32(meta)) or \
                ("packed_crc32" in meta and meta["packed_crc32"] != zlib.crc32(att.data))
            if damaged:
                raise FileFormatError(f"{self.path}: attachment {name} does not match its CRC-32; the file is corrupt: "
                                      f"'caveclod pack {self.path}' stores it again, or rebuild the file")


def refuse_output_path(path: str | os.PathLike) -> None:
    """InputError unless ``path`` can be written as a ``.cvc``: a name in an existing directory,
    not an existing directory, device, FIFO or socket (only a regular file is replaced)."""
    path = Path(path)
    if not path.name or path.name in (".", ".."):
        raise InputError(f"the output {str(path)!r} names no file: give a file name such as mesh.cvc")
    if path.exists() and not path.is_file():
        raise InputError(f"the output {path} exists and is not a regular file (a directory, device or FIFO): "
                         "give the path of a file to write")
    if not path.parent.is_dir():
        raise InputError(f"the output's directory {path.parent} does not exist: create it first")


def _umask() -> int:
    """This process's umask, read where Linux shows it (setting it to read it races other threads)."""
    try:
        with open("/proc/self/status") as fh:
            for line in fh:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError, IndexError):
        pass
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


PART_ARRAYS = ("part_sphere", "part_root_start", "part_roots", "part_face_start", "part_faces")
"""The :class:`caveclod.refine.parts.Parts` fields, in order, as stored."""


def derive_vertex_positions(mesh: StaticMesh) -> np.ndarray:
    """(d,) int32 read-only: the position of each vertex-buffer entry, from ``pos_vstart``."""
    from .kernels.positions import fill_vertex_positions
    ids = np.zeros(mesh.n_vertices, np.int32)
    fill_vertex_positions(np.asarray(mesh.arrays["pos_vstart"]), ids)
    ids.setflags(write=False)           # as a file's map: one compiled variant of the kernels that read it
    return ids


def count_material_faces(mesh: StaticMesh) -> np.ndarray:
    """(m, 2) int64: faces of each material 0 .. m-1 in the full mesh and in the base mesh, m the
    largest material a face has, plus one (the names in the header do not change it)."""
    fm = np.asarray(mesh.arrays["face_material"])
    m = int(fm.max()) + 1 if len(fm) else 0
    # A block at a time: bincount widens its input to int64, which for a whole 33.5M-face
    # mesh was 268 MB of fresh pages (0.5 s of its first camera).
    total = np.zeros(m, np.int64)
    for lo in range(0, len(fm), COUNT_BLOCK):
        total += np.bincount(fm[lo:lo + COUNT_BLOCK], minlength=m)
    return np.stack([total, np.bincount(fm[np.asarray(mesh.arrays["base_faces"])], minlength=m)], axis=1)


def derived_arrays(mesh: StaticMesh, names=DERIVED_ARRAYS) -> dict:
    """The :data:`DERIVED_ARRAYS` in ``names``, derived from ``mesh``'s other arrays (never read
    from its stored ones)."""
    out = {}
    if "vertex_position" in names:
        out["vertex_position"] = derive_vertex_positions(mesh)
    if "material_faces" in names:
        out["material_faces"] = count_material_faces(mesh)
    if any(name in names for name in PART_ARRAYS):
        from .refine.parts import mesh_parts
        parts = mesh_parts(mesh)
        out.update({name: getattr(parts, name.removeprefix("part_")) for name in PART_ARRAYS})
    return {name: a for name, a in out.items() if name in names}


def _read_only(a) -> np.ndarray:
    """A read-only view of ``a`` (a file's maps are read-only already; an in-memory mesh's are not)."""
    v = np.asarray(a).view()
    v.setflags(write=False)
    return v


def load(path: str | os.PathLike, check: bool = True) -> StaticMesh:
    """Open a ``.cvc`` file; arrays are memory-mapped.

    The header is parsed defensively: anything malformed (bad JSON, wrong
    types, missing keys, shapes that disagree with their byte counts, arrays
    outside the file or overlapping) raises :class:`FileFormatError` with one
    line saying what is wrong. ``check`` (the default) then runs
    :func:`caveclod.meshcheck.check_mesh`, the structural check of every id
    the refinement kernels index with (numba checks no bounds): it reads the
    index arrays once (about 60-70 ms per million triangles), but never the
    vertex attributes beyond the positions. ``check=False`` is for tools
    that only read the header or re-hash the file.
    """
    path = Path(path)
    size, hlen, blob = _read_header(path)
    header = _parse_header(path, blob)
    data_start = _aligned(len(MAGIC) + 8 + hlen)
    table = _array_table(path, header["arrays"], data_start, size)
    attached = _attachment_table(path, header.get("attachments", {}), data_start, size)
    _check_overlaps(path, [(start, start + nbytes, f"array {name}") for name, (_, start, nbytes) in table.items()]
                    + [(start, start + nbytes, f"attachment {name}") for name, (_, start, nbytes) in attached.items()])
    arrays = {name: _mapped(path, f"array {name}", DECLARED[name][0], *table[name]) for name in table}
    attachments = {name: Attachment(meta, _mapped(path, f"attachment {name}", np.uint8, (nbytes,), start, nbytes))
                   for name, (meta, start, nbytes) in attached.items()}
    mesh = StaticMesh(arrays=arrays, materials=header["materials"], info=header["info"], path=str(path),
                      content_hash=header["content_hash"], vertex_buffer_hash=header["vertex_buffer_hash"],
                      optional_hash=header.get("optional_hash"),
                      attachments=attachments)
    if check:
        from .meshcheck import check_mesh
        check_mesh(mesh)
    return mesh


# Limits of a sane header. A bit flip or an edit can turn any count into
# something that costs minutes or gigabytes; past these the file is refused.
MAX_HEADER_BYTES = 64 << 20      # the header JSON (a build's is a few KiB)
MAX_MATERIALS = 65536            # face_material is uint16: more names could never be used
MAX_NAME_CHARS = 1024            # characters of one material name
MAX_INFO_DEPTH = 32              # nesting of the build report (a build's is 3 deep)
MAX_ATTACHMENTS = 256            # a build writes two


def damaged_error(path, what: str) -> FileFormatError:
    """The one-line error of a damaged ``.cvc`` file: what is wrong, and what to do."""
    return FileFormatError(f"{path}: {what}; the file is damaged: rebuild it with 'caveclod build' or copy it again")


def _read_header(path: Path) -> tuple[int, int, bytes]:
    """(file size, header length, header bytes) after checking the magic and version."""
    try:
        st = path.stat()
        if not stat.S_ISREG(st.st_mode) and not stat.S_ISDIR(st.st_mode):
            # A FIFO's open() waits for a writer: inspect, pack and serve hung (serve past SIGTERM).
            raise FileFormatError(f"{path}: not a regular file (a FIFO, device or socket); give a .cvc file")
        size = st.st_size
        with open(path, "rb") as fh:
            head = fh.read(len(MAGIC) + 8)
            if len(head) < len(MAGIC) + 8 or head[:len(MAGIC)] != MAGIC:
                raise FileFormatError(f"{path}: not a caveclod .cvc file (bad magic); build one with 'caveclod build'")
            version, hlen = struct.unpack("<II", head[len(MAGIC):])
            if version != VERSION:
                raise FileFormatError(f"{path}: .cvc version {version}, this caveclod reads {VERSION}; rebuild the file")
            if hlen > min(size - len(head), MAX_HEADER_BYTES):
                raise damaged_error(path, f"the header claims {hlen} bytes, the file has {size}")
            blob = fh.read(hlen)
    except FileNotFoundError:
        raise FileFormatError(f"{path}: no such file; build it with 'caveclod build INPUT -o {path.name}'") from None
    except IsADirectoryError:
        raise FileFormatError(f"{path}: is a directory, not a .cvc file") from None
    except PermissionError:
        raise FileFormatError(f"{path}: permission denied; check the file's permissions") from None
    except OSError as exc:
        raise FileFormatError(f"{path}: cannot read: {exc.strerror or exc}") from None
    return size, hlen, blob


def _parse_header(path: Path, blob: bytes) -> dict:
    """The header JSON as a dict whose fields have the right types (defaults filled in)."""
    try:
        header = json.loads(blob)
    except (ValueError, RecursionError):     # bad JSON or UTF-8; RecursionError: nested too deep
        raise damaged_error(path, "the header is truncated or corrupt (not JSON)") from None
    if not isinstance(header, dict):
        raise damaged_error(path, "the header is not a JSON object")
    if header.get("format", "caveclod-static") != "caveclod-static" or header.get("version", VERSION) != VERSION:
        raise damaged_error(path, "the header names another format or version than its first bytes")
    if not isinstance(header.get("arrays"), dict):
        raise damaged_error(path, "the header has no table of arrays")
    for key in ("content_hash", "vertex_buffer_hash", "optional_hash"):
        value = header.get(key, "")                 # absent: StaticMesh computes it (reads the arrays)
        if not isinstance(value, str) or value and (len(value) != 32 or value.strip("0123456789abcdef")):
            raise damaged_error(path, f"the header's {key} is not 32 hex digits")
    header.setdefault("content_hash", "")
    header.setdefault("vertex_buffer_hash", "")
    header["materials"] = _checked_materials(path, header.get("materials", []))
    info = header.setdefault("info", {})
    if not isinstance(info, dict) or _depth(info) > MAX_INFO_DEPTH:
        raise damaged_error(path, "the header's build report (info) is not a JSON object of sane depth")
    origin = info.get("origin")
    if origin is not None and not (isinstance(origin, list) and len(origin) == 3
                                   and all(_finite_number(v) for v in origin)):
        raise damaged_error(path, "the header's origin (info) is not three finite numbers")
    return header


def _finite_number(v) -> bool:
    """A JSON number (not a boolean) that is a finite float (a 400-digit integer is not)."""
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        return False
    try:
        return math.isfinite(float(v))
    except OverflowError:
        return False


def _checked_materials(path: Path, names) -> list:
    if not isinstance(names, list) or not all(isinstance(n, str) for n in names):
        raise damaged_error(path, "the header's materials are not a list of names")
    if len(names) > MAX_MATERIALS:
        raise damaged_error(path, f"the header lists {len(names)} materials, more than the {MAX_MATERIALS} "
                            "that face_material can index")
    if any(len(n) > MAX_NAME_CHARS for n in names):
        raise damaged_error(path, f"a material name is longer than {MAX_NAME_CHARS} characters")
    return names


def _depth(value) -> int:
    """Nesting depth of a parsed JSON value (iterative: the value may be deep)."""
    deepest, todo = 0, [(value, 1)]
    while todo:
        v, depth = todo.pop()
        if isinstance(v, (dict, list)):
            deepest = max(deepest, depth)
            if depth <= MAX_INFO_DEPTH:
                todo.extend((c, depth + 1) for c in (v.values() if isinstance(v, dict) else v))
    return deepest


def _array_table(path: Path, table: dict, data_start: int, size: int) -> dict:
    """{name: (shape, file offset, nbytes)} of every array, checked against :data:`ARRAYS` and the file.

    Each entry must give the declared dtype, a shape of non-negative ints
    with the declared trailing shape, ``nbytes`` equal to what the shape
    holds, and an aligned offset that keeps the bytes inside the file; no
    two arrays may overlap.
    """
    out = {}
    for name, (dtype, trailing) in DECLARED.items():
        t = table.get(name)
        if t is None and name in OPTIONAL_ARRAYS:
            continue
        if not isinstance(t, dict):
            raise damaged_error(path, f"array {name} is missing from the header")
        shape, offset, nbytes = t.get("shape"), t.get("offset"), t.get("nbytes")
        if t.get("dtype") != dtype:
            raise damaged_error(path, f"array {name} has dtype {str(t.get('dtype'))[:20]!r}, not {dtype}")
        if not (isinstance(shape, list) and len(shape) == 1 + len(trailing) and all(_is_count(s) for s in shape)
                and tuple(shape[1:]) == trailing):
            raise damaged_error(path, f"array {name} has shape {str(shape)[:40]}, not (count, *{trailing})")
        if not (_is_count(offset) and _is_count(nbytes)) or offset % ALIGN:
            raise damaged_error(path, f"array {name} has a bad offset or byte count")
        need = int(np.prod(shape, dtype=object)) * np.dtype(dtype).itemsize
        if nbytes != need:
            raise damaged_error(path, f"array {name} of shape {tuple(shape)} holds {need} bytes, the header says {nbytes}")
        if data_start + offset + nbytes > size:
            raise FileFormatError(f"{path}: file is truncated ({size} bytes, array {name} needs "
                                  f"{data_start + offset + nbytes}); rebuild or copy it again")
        out[name] = (tuple(shape), data_start + offset, nbytes)
    return out


def _attachment_table(path: Path, table, data_start: int, size: int) -> dict:
    """{name: (meta, file offset, nbytes)} of the header's attachments, each checked like an array's entry."""
    if not isinstance(table, dict) or len(table) > MAX_ATTACHMENTS:
        raise damaged_error(path, f"the header's attachments are not a JSON object of at most {MAX_ATTACHMENTS}")
    out = {}
    for name, t in table.items():
        if len(name) > MAX_NAME_CHARS or not isinstance(t, dict):
            raise damaged_error(path, f"attachment {name[:40]!r} is not a JSON object")
        offset, nbytes, meta = t.get("offset"), t.get("nbytes"), t.get("meta")
        if not (_is_count(offset) and _is_count(nbytes)) or offset % ALIGN:
            raise damaged_error(path, f"attachment {name[:40]!r} has a bad offset or byte count")
        if not isinstance(meta, dict) or _depth(meta) > MAX_INFO_DEPTH:
            raise damaged_error(path, f"attachment {name[:40]!r} has no metadata object of sane depth")
        if data_start + offset + nbytes > size:
            raise FileFormatError(f"{path}: file is truncated ({size} bytes, attachment {name[:40]!r} needs "
                                  f"{data_start + offset + nbytes}); rebuild or copy it again")
        out[name] = (meta, data_start + offset, nbytes)
    return out


def _check_overlaps(path: Path, spans: list) -> None:
    """Refuse the file when two of ``spans`` [(start, end, what)] share a byte."""
    spans = sorted(s for s in spans if s[1] > s[0])
    for (_, end, a), (start, _, b) in itertools.pairwise(spans):
        if start < end:
            raise damaged_error(path, f"{a} and {b} overlap")


def _mapped(path: Path, what: str, dtype, shape: tuple, start: int, nbytes: int) -> np.ndarray:
    """A read-only memmap of ``shape`` at file offset ``start`` (an empty array when ``nbytes`` is 0)."""
    if nbytes == 0:
        return np.zeros(shape, dtype)
    try:
        return np.memmap(path, dtype=dtype, mode="r", offset=start, shape=shape)
    except (OSError, ValueError) as exc:     # the file changed since its size was read, or mmap failed
        raise FileFormatError(f"{path}: cannot map {what}: {exc}; copy the file again") from None


def _is_count(v) -> bool:
    """A JSON integer >= 0 (``bool`` is an int in Python, but no count)."""
    return isinstance(v, int) and not isinstance(v, bool) and v >= 0


def _as_declared(name: str, a: np.ndarray) -> np.ndarray:
    """``a`` in its declared dtype; refuses values that would not fit."""
    dtype = np.dtype(DECLARED[name][0])
    if dtype.kind in "iu" and a.size and a.dtype != dtype:
        info = np.iinfo(dtype)
        if a.min() < info.min or a.max() > info.max:
            raise FileFormatError(f"{name} holds values outside {dtype}; this mesh does not fit the .cvc format")
    return np.ascontiguousarray(a, dtype=dtype)


def _aligned(n: int) -> int:
    return (n + ALIGN - 1) // ALIGN * ALIGN


def _present(arrays: dict) -> list:
    """Names of :data:`ARRAYS`, then of the :data:`OPTIONAL_ARRAYS` ``arrays`` has, in file order."""
    return [name for name in DECLARED if name in arrays]


def _hashes(arrays: dict) -> tuple[str, str]:
    """(content hash of every array of :data:`ARRAYS`, hash of the vertex buffer alone).

    The optional arrays have a hash of their own (:func:`_optional_hash`):
    the content hash stays the mesh's identity whether or not a file has
    them, and a reader from before one verifies the file as it did.
    """
    content, vb = hashlib.blake2b(digest_size=16), hashlib.blake2b(digest_size=16)
    for name in ARRAYS:
        tag, raw = _tagged_bytes(name, arrays[name])
        content.update(tag)
        content.update(raw)
        if name in VERTEX_BUFFER:
            vb.update(tag)
            vb.update(raw)
    return content.hexdigest(), vb.hexdigest()


def _optional_hash(arrays: dict) -> str:
    """Hash of the :data:`OPTIONAL_ARRAYS` ``arrays`` has ("" when it has none)."""
    names = [name for name in OPTIONAL_ARRAYS if name in arrays]
    if not names:
        return ""
    h = hashlib.blake2b(digest_size=16)
    for name in names:
        tag, raw = _tagged_bytes(name, arrays[name])
        h.update(tag)
        h.update(raw)
    return h.hexdigest()


def _tagged_bytes(name: str, a: np.ndarray) -> tuple[bytes, np.ndarray]:
    """What array ``name`` adds to a hash: its name and shape, then its bytes
    in the declared dtype (a view, without a copy when it has that dtype)."""
    a = np.ascontiguousarray(a, dtype=DECLARED[name][0])
    return f"{name}{a.shape}".encode(), a.reshape(-1).view(np.uint8)
