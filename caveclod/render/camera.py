"""Camera poses, the projection, and the paper's quadrant layout.

Matrices are built in float64 relative to the scene's centre and handed to
the GPU as float32: world coordinates of a 10 km terrain (or of a scan placed
far from the origin) then lose no precision in the vertex shader.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

FIT = 0.99      # near plane slack below the closest point of the scene
NEAR_RATIO = 1.0 / 8192.0
"""Smallest near/far ratio: with a 24-bit depth buffer a depth step at the far
plane is then far * 2**13 / 2**24, i.e. 0.05 % of the distance (7 m at 14 km,
where a 720-pixel, 60-degree image's pixel spans 22 m), so surfaces apart by
more than that never z-fight; an eye outside the scene box gets a far larger
near plane than this floor."""


@dataclass(frozen=True)
class Camera:
    """A camera pose: eye, a point looked at, an up direction (3 floats each),
    and the vertical field of view in degrees."""

    eye: tuple
    target: tuple
    up: tuple = (0.0, 0.0, 1.0)
    fov_y: float = 60.0

    def __post_init__(self):
        for name in ("eye", "target", "up"):
            value = np.asarray(getattr(self, name), dtype=np.float64)
            if value.shape != (3,) or not np.isfinite(value).all():
                raise ValueError(f"Camera.{name} must be three finite numbers, got {getattr(self, name)!r}")
            object.__setattr__(self, name, tuple(value.tolist()))
        if not 0.0 < float(self.fov_y) < 180.0:
            raise ValueError(f"Camera.fov_y must be between 0 and 180 degrees, got {self.fov_y!r}")
        forward = np.subtract(self.target, self.eye)
        if np.linalg.norm(np.cross(forward, self.up)) <= 1e-12 * np.linalg.norm(forward) * np.linalg.norm(self.up):
            raise ValueError("Camera: eye equals target, or up is parallel to the viewing direction")

    @classmethod
    def of(cls, view, fov_y: float = 60.0) -> "Camera":
        """A Camera from ``view``: a Camera, anything with ``eye``, ``target``,
        ``up`` (and ``fov_y``) attributes such as ``caveclod.View``, or a
        sequence ``(eye, target, up[, fov_y])`` such as ``caveclod.paths.Pose``."""
        if isinstance(view, cls):
            return view
        if hasattr(view, "eye"):
            return cls(view.eye, view.target, view.up, float(getattr(view, "fov_y", fov_y)))
        parts = tuple(view)
        if len(parts) not in (3, 4):
            raise ValueError(f"a view is (eye, target, up[, fov_y]); got {len(parts)} items")
        return cls(*parts[:3], float(parts[3]) if len(parts) == 4 else fov_y)

    def view_matrix(self, origin) -> np.ndarray:
        """(4, 4) float64 world-to-eye matrix for coordinates taken relative to ``origin`` (3,)."""
        eye = np.subtract(self.eye, origin)
        f = _unit(np.subtract(self.target, self.eye))
        r = _unit(np.cross(f, self.up))
        u = np.cross(r, f)
        m = np.eye(4)
        m[0, :3], m[1, :3], m[2, :3] = r, u, -f
        m[:3, 3] = -m[:3, :3] @ eye
        return m

    def clip_planes(self, lo, hi, aspect: float) -> tuple[float, float]:
        """(near, far) distances that hold the scene box ``lo``..``hi`` (3,) each.

        far: the deepest box corner along the view. near: the closest any
        point of the box can be along the view inside the frustum (its
        distance times the cosine of the frustum's corner angle), floored at
        :data:`NEAR_RATIO` of far.
        """
        corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
        f = _unit(np.subtract(self.target, self.eye))
        far = max(float(((corners - self.eye) @ f).max()), 1e-30) / FIT
        gap = np.maximum(np.maximum(np.subtract(lo, self.eye), np.subtract(self.eye, hi)), 0.0)
        ty = math.tan(math.radians(self.fov_y) / 2.0)
        corner_cos = 1.0 / math.sqrt(1.0 + ty * ty * (1.0 + aspect * aspect))
        near = max(FIT * float(np.linalg.norm(gap)) * corner_cos, far * NEAR_RATIO)
        return near, max(far, near * 2.0)

    def projection(self, aspect: float, near: float, far: float) -> np.ndarray:
        """(4, 4) float64 OpenGL perspective matrix (vertical fov, width/height ``aspect``)."""
        t = 1.0 / math.tan(math.radians(self.fov_y) / 2.0)
        m = np.zeros((4, 4))
        m[0, 0], m[1, 1] = t / aspect, t
        m[2, 2], m[2, 3] = (far + near) / (near - far), 2.0 * far * near / (near - far)
        m[3, 2] = -1.0
        return m


def quadrants(width: int, height: int, cameras: int) -> list[tuple[int, int, int, int]]:
    """The paper's layout of ``cameras`` (1-4) views in one image.

    Returns:
        One ``(x, y, w, h)`` per camera in image pixels (origin top left):
        one camera fills the image, two sit side by side, three or four share
        a 2 x 2 grid (camera 0 top left, 1 top right, 2 bottom left, 3 bottom
        right).
    """
    if cameras == 1:
        return [(0, 0, width, height)]
    half_w = width // 2
    if cameras == 2:
        return [(0, 0, half_w, height), (half_w, 0, width - half_w, height)]
    half_h = height // 2
    grid = [(0, 0, half_w, half_h), (half_w, 0, width - half_w, half_h),
            (0, half_h, half_w, height - half_h), (half_w, half_h, width - half_w, height - half_h)]
    return grid[:cameras]


def _unit(v) -> np.ndarray:
    v = np.asarray(v, dtype=np.float64)
    return v / np.linalg.norm(v)
