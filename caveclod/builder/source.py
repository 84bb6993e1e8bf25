"""The input of a build: an indexed triangle mesh with per-vertex attributes.

Every loader (mesh files through trimesh, heightfields, the built-in default
terrain) produces a :class:`SourceMesh`; the builder never looks at files.

Terms (DESIGN.md section 2):

* *position*: a unique 3-D location. Positions are welded exactly (bitwise
  equal coordinates become one position).
* *vertex*: one combination of attributes (position, normal, uv, colour) as
  it appears at a face corner. Two vertices never carry identical attributes.
* *material* (the paper's *surface identifier*): one draw batch per material.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..errors import InputError


@dataclass
class SourceMesh:
    """An indexed triangle mesh ready for :func:`caveclod.build`.

    Attributes:
        positions: (e, 3) float64, unique welded positions.
        vertex_position: (v,) int64, the position id of each vertex.
        faces: (p, 3) int64 vertex ids, counter-clockwise seen from outside.
        face_material: (p,) int32 material id of each face.
        materials: names of the materials, indexed by material id.
        vertex_normal: (v, 3) float32 unit normals, or None to compute them
            with a crease angle.
        vertex_uv: (v, 2) float32 texture coordinates, or None.
        vertex_color: (v, 4) uint8 RGBA colours, or None.
        notes: what the loader repaired or dropped, one line each, for the
            build report (for example "dropped 12 degenerate faces").
        crease_angle: degrees; where ``vertex_normal`` is None, the build
            computes normals with this crease angle unless told otherwise:
            30 for meshes (hard edges of CAD and scans become normal seams),
            180 (smooth) for heightfields, where a crease angle would cut
            seams all over rough relief.
    """

    positions: np.ndarray
    vertex_position: np.ndarray
    faces: np.ndarray
    face_material: np.ndarray
    materials: list[str]
    vertex_normal: np.ndarray | None = None
    vertex_uv: np.ndarray | None = None
    vertex_color: np.ndarray | None = None
    notes: list[str] = field(default_factory=list)
    crease_angle: float = 30.0

    @property
    def face_positions(self) -> np.ndarray:
        """(p, 3) int64 position ids of each face corner."""
        return self.vertex_position[self.faces]

    def validate(self) -> None:
        """Raise :class:`InputError` if the arrays are inconsistent.

        Loaders call this last; it is the contract the builder relies on.
        """
        e, v, p = len(self.positions), len(self.vertex_position), len(self.faces)
        if p == 0:
            raise InputError("the mesh has no faces; give a mesh with at least one triangle")
        if self.positions.ndim != 2 or self.positions.shape[1] != 3:
            raise InputError(f"positions must be (e, 3), got {self.positions.shape}")
        if not np.isfinite(self.positions).all():
            raise InputError("positions contain NaN or infinity; fix or remove those vertices")
        if self.faces.ndim != 2 or self.faces.shape[1] != 3:
            raise InputError(f"faces must be (p, 3) triangles, got {self.faces.shape}")
        if self.faces.min() < 0 or self.faces.max() >= v:
            raise InputError("a face refers to a vertex that does not exist")
        if self.vertex_position.min(initial=0) < 0 or self.vertex_position.max(initial=0) >= e:
            raise InputError("a vertex refers to a position that does not exist")
        if self.face_material.shape != (p,):
            raise InputError("face_material must have one entry per face")
        if p and (self.face_material.min() < 0 or self.face_material.max() >= max(len(self.materials), 1)):
            raise InputError("a face refers to a material that does not exist")
        for name, arr, width in (("vertex_normal", self.vertex_normal, 3),
                                 ("vertex_uv", self.vertex_uv, 2),
                                 ("vertex_color", self.vertex_color, 4)):
            if arr is not None:
                if arr.shape != (v, width):
                    raise InputError(f"{name} must be ({v}, {width}), got {arr.shape}")
                if arr.dtype.kind == "f" and not np.isfinite(arr).all():
                    raise InputError(f"{name} contains NaN or infinity")
        fp = self.face_positions
        if ((fp[:, 0] == fp[:, 1]) | (fp[:, 1] == fp[:, 2]) | (fp[:, 2] == fp[:, 0])).any():
            raise InputError("a face uses the same position twice; the loader must drop degenerate faces")
