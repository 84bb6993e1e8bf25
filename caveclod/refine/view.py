"""A camera's view: pose, projection and refinement tolerance.

The screen-space error of a node (DESIGN.md section 3) is
``error_px = err_obj * kappa / distance`` with
``kappa = viewport_height / (2 tan(fov_y / 2))``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..errors import InputError

# Layout of the float64 parameter vector the kernels read.
P_EYE = 0            # 3: eye position
P_PLANES = 3         # 5 x 4: left, right, bottom, top, near; a.x + d >= 0 inside
P_KAPPA = 23         # pixels per unit of error at unit distance
P_TOL = 24           # tolerance in pixels
P_CULL = 25          # 1.0: frustum culling on
P_BACKFACE = 26      # 1.0: back-face culling on
P_PRUNE = 27         # 1.0: parts smaller than the tolerance may vanish
P_SIZE = 28


@dataclass(frozen=True)
class View:
    """One camera pose and the refinement criteria for it.

    Args:
        eye, target, up: world-space points / direction (3 floats each).
        fov_y: vertical field of view in degrees, in (0, 180).
        width, height: viewport in pixels.
        tolerance_px: screen-space error allowed, in pixels. ``0`` refines
            every node the culling keeps.
        cull: coarsen what lies outside the view frustum.
        backface: coarsen regions whose normal cone faces wholly away.
        prune: hide a whole connected part while it projects smaller than
            the tolerance (its bounding sphere's diameter under
            ``tolerance_px``) or, with ``cull``, lies wholly outside the
            frustum, so that a mesh of many small parts seen from afar draws
            almost nothing (:mod:`caveclod.kernels.parts`).
    """

    eye: tuple = (0.0, -1.0, 1.0)
    target: tuple = (0.0, 0.0, 0.0)
    up: tuple = (0.0, 0.0, 1.0)
    fov_y: float = 60.0
    width: int = 1280
    height: int = 720
    tolerance_px: float = 1.0
    cull: bool = True
    backface: bool = False
    prune: bool = True

    def __post_init__(self):
        # Plain floats throughout: a server builds a View for every pose it
        # receives, and numpy's small-vector calls cost more than the rest
        # of its handling of a pose.
        eye, target, up = check_pose(self.eye, self.target, self.up)
        object.__setattr__(self, "eye", eye)
        object.__setattr__(self, "target", target)
        object.__setattr__(self, "up", up)
        for name, kind in (("fov_y", float), ("tolerance_px", float), ("width", int), ("height", int)):
            value = getattr(self, name)
            try:
                number = kind(value)
            except (TypeError, ValueError, OverflowError):
                raise InputError(f"View.{name} must be a number, got {value!r}") from None
            if kind is float and not math.isfinite(number):
                raise InputError(f"View.{name} must be finite, got {value!r}")
            object.__setattr__(self, name, number)
        if not 0.0 < self.fov_y < 180.0:
            raise InputError(f"View.fov_y must be between 0 and 180 degrees, got {self.fov_y}")
        if self.width < 1 or self.height < 1:
            raise InputError(f"View viewport must be at least 1x1 pixels, got {self.width}x{self.height}")
        if self.tolerance_px < 0:
            raise InputError(f"View.tolerance_px must be >= 0, got {self.tolerance_px}")
        half = math.tan(math.radians(self.fov_y) / 2.0)
        if half == 0.0 or not math.isfinite(self.height / (2.0 * half)):
            raise InputError(f"View.fov_y {self.fov_y} degrees is so narrow that pixels per unit of error overflow "
                             f"with a viewport of {self.height} pixels; use a field of view of a degree or more")

    @classmethod
    def from_pose(cls, pose, **options) -> "View":
        """A view from a :class:`caveclod.paths.Pose` (eye, target, up) and options."""
        eye, target, up = pose
        return cls(eye=eye, target=target, up=up, **options)

    def params(self) -> np.ndarray:
        """The (P_SIZE,) float64 vector the refinement kernels read (computed
        once per view; plain floats, because numpy's small-vector calls cost
        more than the refinement of a converged camera)."""
        cached = self.__dict__.get("_params")
        if cached is not None:
            return cached
        vp = view_params(self.eye, self.target, self.up, self.fov_y, self.width, self.height, self.tolerance_px,
                         self.cull, self.backface, self.prune)
        object.__setattr__(self, "_params", vp)
        return vp


def view_params(eye: tuple, target: tuple, up: tuple, fov_y: float, width: int, height: int,
                tolerance_px: float, cull: bool, backface: bool, prune: bool = True) -> np.ndarray:
    """The (P_SIZE,) float64 vector the refinement kernels read, of a pose
    already checked (:func:`check_pose`) and options already validated (a
    :class:`View`'s). A server calls it directly for every update, without
    the View a library user builds."""
    ex, ey, ez = eye
    f = _unit((target[0] - ex, target[1] - ey, target[2] - ez))
    r = _unit(_cross(f, up))
    u = _cross(r, f)
    ty = math.tan(math.radians(fov_y) / 2.0)
    tx = ty * width / height
    # Inward normals of the four side planes through the eye, and near.
    normals = [tuple(a * tx + b for a, b in zip(f, r)), tuple(a * tx - b for a, b in zip(f, r)),
               tuple(a * ty + b for a, b in zip(f, u)), tuple(a * ty - b for a, b in zip(f, u)), f]
    out = [ex, ey, ez]
    for n in normals:
        n = _unit(n)
        out += [n[0], n[1], n[2], -(n[0] * ex + n[1] * ey + n[2] * ez)]
    out += [height / (2.0 * ty), float(tolerance_px), 1.0 if cull else 0.0, 1.0 if backface else 0.0,
            1.0 if prune else 0.0]
    vp = np.array(out)
    vp.flags.writeable = False
    return vp


def check_pose(eye, target, up) -> tuple[tuple, tuple, tuple]:
    """``(eye, target, up)`` as float triples; InputError (one line) for a pose
    no camera can take: not three numbers each, NaN or infinite, eye ==
    target, or up parallel to the viewing direction (or zero).

    Plain floats: a server checks every pose it receives, most of which a
    newer one replaces before any refinement reads it.
    """
    out = []
    for name, v in (("eye", eye), ("target", target), ("up", up)):
        try:
            x, y, z = v
            t = (float(x), float(y), float(z))
        except (TypeError, ValueError):
            raise InputError(f"View.{name} must be three numbers, got {v!r}") from None
        if not (math.isfinite(t[0]) and math.isfinite(t[1]) and math.isfinite(t[2])):
            raise InputError(f"View.{name} is not finite ({v!r}); send a pose without NaN or infinity")
        out.append(t)
    eye, target, up = out
    up = _tamed(up)
    forward = (target[0] - eye[0], target[1] - eye[1], target[2] - eye[2])
    if _norm(forward) == 0.0:
        raise InputError("View.eye and View.target are the same point; look somewhere")
    if not math.isfinite(_norm(forward)):          # (up is tamed: its length is finite)
        raise InputError("View.eye and View.target are too far apart for the frustum's "
                         "arithmetic (it overflows); send coordinates of the mesh's scale")
    if _norm(_cross(forward, up)) <= 1e-12 * _norm(forward) * _norm(up):
        raise InputError("View.up is parallel to the viewing direction (or zero); give an up vector across it")
    return eye, target, up


def _tamed(v: tuple) -> tuple:
    """``v``, or when its components are so small (or large) that their squares underflow (or
    overflow), ``v`` scaled by a power of two, exactly, to a largest component in [0.5, 1).

    Only its direction matters (an up vector). A length that underflowed to 0 would pass
    the parallel test and then divide by zero in :func:`view_params`.
    """
    m = max(abs(v[0]), abs(v[1]), abs(v[2]))
    if m == 0.0 or 2.0 ** -400 < m < 2.0 ** 400:
        return v
    e = math.frexp(m)[1]
    return (math.ldexp(v[0], -e), math.ldexp(v[1], -e), math.ldexp(v[2], -e))


def _cross(a, b) -> tuple:
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


def _norm(a) -> float:
    return math.sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2])


def _unit(a) -> tuple:
    n = _norm(a)
    return (a[0] / n, a[1] / n, a[2] / n)
