"""Camera paths over a mesh: the flyovers of the paper's experiments (4.1).

Each camera circles over its own quadrant of the mesh's bounding box at a
steady speed, looking ahead and down, so that cameras see different parts
of the terrain (the paper's cameras A-D). Used by the demo and benchmarks.
"""

from __future__ import annotations

import math

import numpy as np

from .view import View


def mesh_bounds(mesh) -> tuple[np.ndarray, np.ndarray]:
    """(lo, hi) float64 (3,) corners of the axis-aligned bounding box."""
    pos = np.asarray(mesh.vertex_positions, dtype=np.float64)
    return pos.min(axis=0), pos.max(axis=0)


def flyover_view(lo, hi, camera: int, t: float, *, seconds_per_lap: float = 60.0,
                 width: int = 1280, height: int = 720, fov_y: float = 60.0,
                 tolerance_px: float = 1.0, **view_options) -> View:
    """The view of ``camera`` (0, 1, 2, ...) at time ``t`` seconds.

    Camera k circles the centre of quadrant k % 4 (radius a fifth of the
    extent), at a height of a tenth of the extent above the highest point,
    looking a tenth of the extent ahead at mid height. Its speed is one lap
    per ``seconds_per_lap``: about 200 m/s over the 10 km default terrain.
    """
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    extent = float(max(hi[0] - lo[0], hi[1] - lo[1]))
    quadrant = camera % 4
    centre = lo[:2] + (hi[:2] - lo[:2]) * np.array([0.25 + 0.5 * (quadrant % 2), 0.25 + 0.5 * (quadrant // 2)])
    radius = 0.2 * extent
    direction = 1.0 if camera % 2 == 0 else -1.0       # neighbours circle opposite ways
    phase = direction * 2.0 * math.pi * t / seconds_per_lap + camera * 1.3
    eye_xy = centre + radius * np.array([math.cos(phase), math.sin(phase)])
    heading = np.array([-math.sin(phase), math.cos(phase)]) * direction
    eye = np.r_[eye_xy, hi[2] + 0.1 * extent]
    target = np.r_[eye_xy + 0.1 * extent * heading, 0.5 * (lo[2] + hi[2])]
    return View(eye=tuple(eye), target=tuple(target), up=(0.0, 0.0, 1.0), fov_y=fov_y,
                width=width, height=height, tolerance_px=tolerance_px, **view_options)
