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

import numpy as np


class Pose(NamedTuple):
    """A camera pose: eye, a point looked at, and an up direction (3 floats each)."""

    eye: tuple
    target: tuple
    up: tuple


UP = (0.0, 0.0, 1.0)


def _box(lo, hi):
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    extent = float(max(hi[0] - lo[0], hi[1] - lo[1], 1e-9))
    centre = 0.5 * (lo + hi)
    terrain = (hi[2] - lo[2]) < extent / 3.0
    return lo, hi, extent, centre, terrain


def _pose(eye, target, up=UP) -> Pose:
    return Pose(tuple(float(v) for v in eye), tuple(float(v) for v in target), tuple(float(v) for v in up))


def flyover(lo, hi, camera: int, t: float, *, seconds_per_lap: float = 60.0) -> Pose:
    """Camera k circles the centre of quadrant k % 4 (radius a fifth of the
    extent), at a tenth of the extent above the highest point, looking a
    tenth of the extent ahead at mid height. One lap per ``seconds_per_lap``:
    about 200 m/s over the 10 km default terrain. Neighbours circle opposite
    ways.
    """
    lo, hi, extent, _, _ = _box(lo, hi)
    quadrant = camera % 4
    centre = lo[:2] + (hi[:2] - lo[:2]) * np.array([0.25 + 0.5 * (quadrant % 2), 0.25 + 0.5 * (quadrant // 2)])
    radius = 0.2 * extent
    direction = 1.0 if camera % 2 == 0 else -1.0
    phase = direction * 2.0 * math.pi * t / seconds_per_lap + camera * 1.3
    eye_xy = centre + radius * np.array([math.cos(phase), math.sin(phase)])
    heading = np.array([-math.sin(phase), math.cos(phase)]) * direction
    eye = np.r_[eye_xy, hi[2] + 0.1 * extent]
    target = np.r_[eye_xy + 0.1 * extent * heading, 0.5 * (lo[2] + hi[2])]
    return _pose(eye, target)


def circle(lo, hi, camera: int, t: float, *, seconds_per_lap: float = 60.0) -> Pose:
    """An orbit round the centre, looking at it; camera k starts k quarter-turns on.

    Terrain: radius 0.45 extent, height 0.15 extent above the top. Object:
    radius 1.5 extent, at the centre's height.
    """
    lo, hi, extent, centre, terrain = _box(lo, hi)
    phase = 2.0 * math.pi * t / seconds_per_lap + camera * 0.5 * math.pi
    radius = (0.45 if terrain else 1.5) * extent
    eye = centre + radius * np.array([math.cos(phase), math.sin(phase), 0.0])
    if terrain:
        eye[2] = hi[2] + 0.15 * extent
    return _pose(eye, centre)


def rotate(lo, hi, camera: int, t: float, *, period: float = 8.0, degrees: float = 15.0) -> Pose:
    """A fixed eye whose view direction swings +-``degrees`` about the centre
    (yaw, sinusoidal, one swing per ``period`` seconds); camera k looks from
    k quarter-turns round.
    """
    lo, hi, extent, centre, terrain = _box(lo, hi)
    around = camera * 0.5 * math.pi - 0.5 * math.pi
    distance = (0.6 if terrain else 1.5) * extent
    eye = centre + distance * np.array([math.cos(around), math.sin(around), 0.0])
    if terrain:
        eye[2] = hi[2] + 0.1 * extent
    swing = math.radians(degrees) * math.sin(2.0 * math.pi * t / period)
    look = centre - eye
    c, s = math.cos(swing), math.sin(swing)
    look = np.array([c * look[0] - s * look[1], s * look[0] + c * look[1], look[2]])
    return _pose(eye, eye + look)


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
    d = np.array([math.cos(angle), math.sin(angle), 0.0])
    if terrain:
        eye = centre + (s - 0.5) * 0.9 * extent * d
        eye[2] = hi[2] + 0.1 * extent
        forward = d if phase <= 1.0 else -d
        target = eye + 0.1 * extent * forward
        target[2] = 0.5 * (lo[2] + hi[2])
        return _pose(eye, target)
    distance = (2.0 - 1.4 * s) * extent
    return _pose(centre - distance * d, centre)


PATHS = {"flyover": flyover, "circle": circle, "rotate": rotate, "line": line}


def pose(path: str, lo, hi, camera: int, t: float) -> Pose:
    """The pose on the named path (see :data:`PATHS`) of ``camera`` at ``t`` seconds."""
    try:
        fn = PATHS[path]
    except KeyError:
        raise ValueError(f"unknown path {path!r}; choose one of {', '.join(PATHS)}") from None
    return fn(lo, hi, camera, t)
