"""Camera paths over a mesh's bounding box: the poses of flyovers and tests.

Plain numpy, no core and no network: the demo and benchmarks (through
:class:`caveclod.refine.view.View`) and the thin clients (load tester,
renderer) fly the same paths. Each function maps ``(lo, hi, camera, t)`` to a
:class:`Pose`; ``lo``/``hi`` are the (3,) corners of the mesh's bounding box,
``camera`` is 0, 1, 2, ... and ``t`` is seconds.

Paths (``PATHS``):

* ``flyover``: the paper's experiments (Kram & Shaw 4.1). Camera k circles
  over quadrant k % 4 at a steady speed, looking ahead and down, so cameras
  see different parts of the mesh (cameras A-D).
* ``circle``: an orbit round the mesh, looking at its centre (Lario et al.,
  trajectory A).
* ``rotate``: a fixed eye whose view swings by small rotations (trajectory B).
* ``line``: a straight line: over a terrain, across it at a steady height;
  round an object, towards its centre and back out (trajectory C, zoom in/out).

A box whose height is under a third of its width is treated as a terrain
(``z`` up): paths stay above it. Otherwise it is an object seen from all round.
"""

from __future__ import annotations

import math
from typing import NamedTuple


class Pose(NamedTuple):
    """A camera pose: eye, a point looked at, and an up direction (3 floats each)."""

    eye: tuple
    target: tuple
    up: tuple


UP = (0.0, 0.0, 1.0)

# Plain floats: a load generator computes a pose per camera 30 times a second
# for dozens of sessions, and numpy's small-array calls cost ten times more.


def _box(lo, hi):
    lo, hi = tuple(float(v) for v in lo), tuple(float(v) for v in hi)
    extent = max(hi[0] - lo[0], hi[1] - lo[1], 1e-9)
    centre = tuple(0.5 * (a + b) for a, b in zip(lo, hi))
    terrain = (hi[2] - lo[2]) < extent / 3.0
    return lo, hi, extent, centre, terrain


def flyover(lo, hi, camera: int, t: float, *, seconds_per_lap: float = 60.0) -> Pose:
    """Camera k circles the centre of quadrant k % 4 (radius a fifth of the
    extent), at a tenth of the extent above the highest point, looking a
    tenth of the extent ahead at mid height. One lap per ``seconds_per_lap``:
    about 200 m/s over the 10 km default terrain. Neighbours circle opposite
    ways.
    """
    lo, hi, extent, _, _ = _box(lo, hi)
    quadrant = camera % 4
    cx = lo[0] + (hi[0] - lo[0]) * (0.25 + 0.5 * (quadrant % 2))
    cy = lo[1] + (hi[1] - lo[1]) * (0.25 + 0.5 * (quadrant // 2))
    radius = 0.2 * extent
    direction = 1.0 if camera % 2 == 0 else -1.0
    phase = direction * 2.0 * math.pi * t / seconds_per_lap + camera * 1.3
    ex, ey = cx + radius * math.cos(phase), cy + radius * math.sin(phase)
    hx, hy = -math.sin(phase) * direction, math.cos(phase) * direction
    eye = (ex, ey, hi[2] + 0.1 * extent)
    target = (ex + 0.1 * extent * hx, ey + 0.1 * extent * hy, 0.5 * (lo[2] + hi[2]))
    return Pose(eye, target, UP)


def circle(lo, hi, camera: int, t: float, *, seconds_per_lap: float = 60.0) -> Pose:
    """An orbit round the centre, looking at it; camera k starts k quarter-turns on.

    Terrain: radius 0.45 extent, height 0.15 extent above the top. Object:
    radius 1.5 extent, at the centre's height.
    """
    lo, hi, extent, centre, terrain = _box(lo, hi)
    phase = 2.0 * math.pi * t / seconds_per_lap + camera * 0.5 * math.pi
    radius = (0.45 if terrain else 1.5) * extent
    eye = (centre[0] + radius * math.cos(phase), centre[1] + radius * math.sin(phase),
           hi[2] + 0.15 * extent if terrain else centre[2])
    return Pose(eye, centre, UP)


def rotate(lo, hi, camera: int, t: float, *, period: float = 8.0, degrees: float = 15.0) -> Pose:
    """A fixed eye whose view direction swings +-``degrees`` about the centre
    (yaw, sinusoidal, one swing per ``period`` seconds); camera k looks from
    k quarter-turns round.
    """
    lo, hi, extent, centre, terrain = _box(lo, hi)
    around = camera * 0.5 * math.pi - 0.5 * math.pi
    distance = (0.6 if terrain else 1.5) * extent
    eye = (centre[0] + distance * math.cos(around), centre[1] + distance * math.sin(around),
           hi[2] + 0.1 * extent if terrain else centre[2])
    swing = math.radians(degrees) * math.sin(2.0 * math.pi * t / period)
    lx, ly, lz = centre[0] - eye[0], centre[1] - eye[1], centre[2] - eye[2]
    c, s = math.cos(swing), math.sin(swing)
    return Pose(eye, (eye[0] + c * lx - s * ly, eye[1] + s * lx + c * ly, eye[2] + lz), UP)


def line(lo, hi, camera: int, t: float, *, seconds: float = 20.0) -> Pose:
    """A straight line at steady speed, there and back every ``2 * seconds``.

    Terrain: across the box at 0.1 extent above the top, looking ahead and
    down; camera k crosses in direction k quarter-turns round. Object: from
    2 extents away towards 0.6 extent from the centre, looking at it.
    """
    lo, hi, extent, centre, terrain = _box(lo, hi)
    phase = (t / seconds) % 2.0
    s = phase if phase <= 1.0 else 2.0 - phase        # 0 -> 1 -> 0
    angle = camera * 0.5 * math.pi
    dx, dy = math.cos(angle), math.sin(angle)
    if terrain:
        k = (s - 0.5) * 0.9 * extent
        eye = (centre[0] + k * dx, centre[1] + k * dy, hi[2] + 0.1 * extent)
        forward = 1.0 if phase <= 1.0 else -1.0
        target = (eye[0] + 0.1 * extent * forward * dx, eye[1] + 0.1 * extent * forward * dy, 0.5 * (lo[2] + hi[2]))
        return Pose(eye, target, UP)
    distance = (2.0 - 1.4 * s) * extent
    return Pose((centre[0] - distance * dx, centre[1] - distance * dy, centre[2]), centre, UP)


PATHS = {"flyover": flyover, "circle": circle, "rotate": rotate, "line": line}


def pose(path: str, lo, hi, camera: int, t: float) -> Pose:
    """The pose on the named path (see :data:`PATHS`) of ``camera`` at ``t`` seconds."""
    try:
        fn = PATHS[path]
    except KeyError:
        raise ValueError(f"unknown path {path!r}; choose one of {', '.join(PATHS)}") from None
    return fn(lo, hi, camera, t)
