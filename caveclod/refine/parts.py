"""The connected parts of a static mesh, for hiding parts smaller than the tolerance.

Derived from the base mesh when the first camera is made (it is small: a
few faces per part), not stored in the ``.cvc`` file, so every file built so
far prunes too. See :mod:`caveclod.kernels.parts` for how cameras use them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..kernels.parts import label_parts, part_spheres, position_parts


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
    """The :class:`Parts` of a :class:`~caveclod.staticmesh.StaticMesh`."""
    a = mesh.arrays
    nodes = np.asarray(a["base_face_nodes"], np.int32)
    label = label_parts(nodes, mesh.n_nodes) if len(nodes) else np.zeros(0, np.int32)
    m = int(label.max(initial=-1)) + 1
    faces = np.argsort(label, kind="stable").astype(np.int32)
    face_start = np.searchsorted(label[faces], np.arange(m + 1)).astype(np.int64)
    # (part, root) pairs, unique, sorted by part then root.
    pairs = np.unique(np.c_[np.repeat(label, 3).astype(np.int64), nodes.ravel()], axis=0)
    roots = pairs[:, 1].astype(np.int32)
    root_start = np.searchsorted(pairs[:, 0], np.arange(m + 1)).astype(np.int64)
    return Parts(_spheres(mesh, roots, root_start), root_start, roots, face_start, faces)


def position_part(mesh) -> np.ndarray:
    """(e,) int32 part of each original position of ``mesh``, -1 for none (one pass over the nodes)."""
    parts = mesh.parts()
    return _position_part(mesh, parts.roots, parts.root_start)


def _position_part(mesh, roots: np.ndarray, root_start: np.ndarray) -> np.ndarray:
    root_part = np.full(mesh.n_nodes, -1, np.int32)
    root_part[roots] = np.repeat(np.arange(len(root_start) - 1, dtype=np.int32), np.diff(root_start))
    return position_parts(np.asarray(mesh.arrays["node_parent"]), mesh.n_positions, root_part)


def _spheres(mesh, roots: np.ndarray, root_start: np.ndarray) -> np.ndarray:
    """(m, 4) float64 sphere around each part's original positions."""
    part = _position_part(mesh, roots, root_start)
    return part_spheres(np.ascontiguousarray(mesh.positions), part, len(root_start) - 1)
