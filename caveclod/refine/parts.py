"""The connected parts of a static mesh, for hiding parts smaller than the tolerance.

Derived from the base mesh (it is small: a few faces per part) and one pass
over the nodes; the build stores the result in the ``.cvc`` file
(:data:`caveclod.staticmesh.DERIVED_ARRAYS`), and a file without it (built
before 2026-11-29) has it derived when its first camera is made, so every
file prunes. See :mod:`caveclod.kernels.parts` for how cameras use them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..kernels.parts import label_parts, part_spheres, spread_parts


@dataclass(frozen=True)
class Parts:
    """Connected components of the base mesh.

    Attributes:
        sphere: (m, 4) float64 centre and radius enclosing every original
            position of each part (:func:`caveclod.kernels.parts.part_spheres`).
        root_start, roots: CSR (m+1,) int64 / (r,) int32: root nodes of each
            part, ascending.
        face_start, faces: CSR (m+1,) int64 / (k,) int32: rows of the base
            arrays (``base_faces`` ...) of each part, ascending.
    """

    sphere: np.ndarray
    root_start: np.ndarray
    roots: np.ndarray
    face_start: np.ndarray
    faces: np.ndarray

    @property
    def count(self) -> int:
        return len(self.sphere)

    @property
    def nbytes(self) -> int:
        return int(sum(a.nbytes for a in (self.sphere, self.root_start, self.roots, self.face_start, self.faces)))


def mesh_parts(mesh) -> Parts:
    """The :class:`Parts` of a :class:`~caveclod.staticmesh.StaticMesh`.

    Transient memory: the base mesh's few arrays and one int32 per node (the
    pass that gives each position its part); positions are read in place."""
    a = mesh.arrays
    nodes = np.asarray(a["base_face_nodes"], np.int32)
    # Union-find over the base mesh's own nodes, numbered locally: a scratch array per
    # node of the whole hierarchy would be 0.8 GB at 200M triangles.
    used, local = np.unique(nodes, return_inverse=True)
    label = label_parts(local.reshape(-1, 3).astype(np.int32), len(used)) if len(nodes) else np.zeros(0, np.int32)
    m = int(label.max(initial=-1)) + 1
    faces = np.argsort(label, kind="stable").astype(np.int32)
    face_start = np.searchsorted(label[faces], np.arange(m + 1)).astype(np.int64)
    # (part, root) pairs, unique, sorted by part then root.
    pairs = np.unique(np.c_[np.repeat(label, 3).astype(np.int64), nodes.ravel()], axis=0)
    roots = pairs[:, 1].astype(np.int32)
    root_start = np.searchsorted(pairs[:, 0], np.arange(m + 1)).astype(np.int64)
    part = _node_part(mesh, roots, root_start)
    sphere = part_spheres(np.asarray(a["vertex_positions"]), np.asarray(a["pos_vstart"]), part, m)
    out = (sphere, root_start, roots, face_start, faces)
    for x in out:
        x.setflags(write=False)         # as a file's maps: one compiled variant of the kernels that read them
    return Parts(*out)


def position_part(mesh) -> np.ndarray:
    """(e,) int32 part of each original position of ``mesh``, -1 for none (one pass over the nodes)."""
    parts = mesh.parts()
    return _node_part(mesh, parts.roots, parts.root_start)[:mesh.n_positions]


def _node_part(mesh, roots: np.ndarray, root_start: np.ndarray) -> np.ndarray:
    """(n,) int32 part of every node (its root's)."""
    part = np.full(mesh.n_nodes, -1, np.int32)
    part[roots] = np.repeat(np.arange(len(root_start) - 1, dtype=np.int32), np.diff(root_start))
    spread_parts(np.asarray(mesh.arrays["node_parent"]), part)
    return part
