"""Moving a mesh to its own origin, for models in world coordinates.

The .cvc stores positions as float32, whose step near a coordinate x is
about ``x * 1.2e-7``: 0.25 m at a UTM northing of 4,100,000 m, 0.5 m in
Earth-centred coordinates. Scans, photogrammetry and city models exported
in such coordinates lose their detail there (faces that collapse are
refused; the rest are rounded, the report notes by how much). ``caveclod
build --origin auto`` subtracts a point near the mesh's centre from every
position before the build, and the file records it (``info["origin"]``),
so that positions keep float32's full precision and anything placing the
mesh in the world can add it back. Poses are then given in the mesh's own
coordinates.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from ..errors import InputError
from .source import MAX_COORDINATE, SourceMesh, out_of_range_rows

FLOAT32_ROUNDING_NOTE = 0.01
"""Share of the median edge length by which rounding positions to float32 may move them before
the build's report notes it."""


def parse_origin(value) -> str | tuple[float, float, float] | None:
    """``--origin``'s value: None, ``"auto"``, or three finite numbers (a string ``"x,y,z"`` or a sequence)."""
    if value is None or (isinstance(value, str) and value.strip().lower() == "auto"):
        return None if value is None else "auto"
    parts = value.split(",") if isinstance(value, str) else value
    try:
        xyz = tuple(float(v) for v in parts)
    except (TypeError, ValueError):
        xyz = ()
    if len(xyz) != 3 or not all(math.isfinite(v) for v in xyz):
        raise InputError(f"--origin must be 'auto' or three finite numbers x,y,z, got {value!r}")
    return xyz


def move_to_origin(source: SourceMesh, origin) -> SourceMesh:
    """``source`` with ``origin`` (see :func:`parse_origin`) as the world point its positions start
    from: a new SourceMesh (the caller's is not changed), or ``source`` itself for None.

    ``"auto"``: the bounding box's centre, rounded to whole units. A point
    (x, y, z) is in world coordinates: for a heightfield that already said
    where it lies (``source.origin``, its south-west sample), positions
    move by the difference, so that the recorded origin is the point given.
    """
    origin = parse_origin(origin)
    if origin is None:
        return source
    p = source.positions
    known = np.asarray(source.origin or (0.0, 0.0, 0.0), np.float64)
    if origin == "auto":
        shift = np.round((p.min(axis=0) + p.max(axis=0)) / 2.0)
        recorded = tuple(float(v) for v in known + shift)
    else:
        shift, recorded = np.asarray(origin, np.float64) - known, origin
    with np.errstate(over="ignore", invalid="ignore"):
        moved = p - shift
    n_far = int(out_of_range_rows(moved).sum())
    if n_far:
        raise InputError(f"--origin {recorded[0]:g},{recorded[1]:g},{recorded[2]:g} puts {n_far:,} positions beyond "
                         f"+-{MAX_COORDINATE:.2g}, too far for the .cvc's float32; give a point near the mesh, or auto")
    note = (f"positions are relative to the origin ({recorded[0]:.10g}, {recorded[1]:.10g}, {recorded[2]:.10g}) "
            "(info origin): add it back to place the mesh in the world")
    return replace(source, positions=moved, origin=recorded, notes=[*source.notes, note])


def float32_rounding_note(positions: np.ndarray, face_pos: np.ndarray) -> str | None:
    """A note when storing (e, 3) float64 ``positions`` as float32 moves them by more than
    :data:`FLOAT32_ROUNDING_NOTE` of the median edge of the (p, 3) faces ``face_pos`` (sampled), else None."""
    moved = float(np.abs(positions - positions.astype(np.float32)).max(initial=0.0))
    if moved == 0.0 or len(face_pos) == 0:
        return None
    sample = face_pos[:: max(1, len(face_pos) // 100_000)]
    edges = np.linalg.norm(positions[sample[:, 1]] - positions[sample[:, 0]], axis=1)
    median = float(np.median(edges))
    if not median > 0.0 or not moved > FLOAT32_ROUNDING_NOTE * median:
        return None
    return (f"the .cvc stores positions as float32, which moves them by up to {moved:.3g} here, "
            f"{100 * moved / median:.0f} % of the median edge ({median:.3g}): the mesh lies far from its origin; "
            "build with --origin auto to keep its detail")
