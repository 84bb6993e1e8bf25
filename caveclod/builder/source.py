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

FLOAT32_MAX = float(np.finfo(np.float32).max)
"""Largest finite float32 (about 3.4e38): the .cvc stores positions, texture
coordinates, bounding spheres and error bounds as float32."""

MAX_COORDINATE = 2.0 ** 62
"""Largest coordinate magnitude a build accepts (about 4.6e18).

The build itself works in float64, where nothing it forms comes near
overflow for such coordinates: its largest products are of degree four in
the coordinates (a quadric entry is a face's area times its squared plane
offset; the point-triangle distance multiplies two dot products of edges),
at most (2^63)^4 = 2^252, about 7e75, against float64's 1.8e308. What
limits the coordinates is float32, in which the .cvc stores the positions
and the bounding spheres and errors of its nodes, and in which viewers get
the positions: with every coordinate within +-2^62 a coordinate difference
is within +-2^63 and the squared distance between any two positions (three
such squares, at most 3 * 2^126, about 2.6e38) is still a finite float32, so
a distance, norm or bound a viewer computes from the file's float32 arrays
stays finite. No real model comes near: 4.6e18 metres is about 490 light
years, and 4.6e18 millimetres about 31,000 astronomical units."""


def out_of_range_rows(values: np.ndarray, limit: float = MAX_COORDINATE) -> np.ndarray:
    """(n,) bool: rows of the (n, k) ``values`` holding a NaN, an infinity or a
    magnitude beyond ``limit``."""
    with np.errstate(invalid="ignore"):
        return ~(np.abs(values) <= limit).all(axis=1)


@dataclass
class SourceMesh:
    """An indexed triangle mesh ready for :func:`caveclod.build`.

    Attributes:
        positions: (e, 3) float64, unique welded positions.
        vertex_position: (v,) int64, the position id of each vertex.
        faces: (p, 3) int32 or int64 vertex ids, counter-clockwise seen from outside.
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
    origin: tuple[float, float, float] | None = None   # subtracted from the input's positions (builder/origin.py)

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
        n_far = int(out_of_range_rows(self.positions).sum())
        if n_far:
            raise InputError(f"{n_far} positions have coordinates beyond +-{MAX_COORDINATE:.2g}, where float32 "
                             "(what the .cvc stores) cannot hold squared distances; scale the mesh down")
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
                if arr.dtype.kind == "f" and out_of_range_rows(arr, FLOAT32_MAX).any():
                    raise InputError(f"{name} contains NaN, infinity or values beyond float32's range")
        fp = self.face_positions
        if ((fp[:, 0] == fp[:, 1]) | (fp[:, 1] == fp[:, 2]) | (fp[:, 2] == fp[:, 0])).any():
            raise InputError("a face uses the same position twice; the loader must drop degenerate faces")
