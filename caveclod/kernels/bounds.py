"""Bounding spheres, normal cones and quadrics as small float64 arrays.

A sphere is ``(cx, cy, cz, r)``. A normal cone is ``(ax, ay, az, half_angle)``
with a unit axis; ``half_angle < 0`` means empty and ``>= pi`` means every
direction. A quadric is the 10 upper-triangle entries of a symmetric 4x4
(Garland-Heckbert): ``a2 ab ac ad b2 bc bd c2 cd d2``.
"""

import math

import numba as nb
import numpy as np

PAD = 1e-9   # relative growth per merge so containment survives rounding


@nb.njit(cache=True, nogil=True, inline="always")
def sphere_add_sphere(s, c0, c1, c2, r):
    """Grow sphere ``s`` (4,) in place to contain sphere (c, r)."""
    dx, dy, dz = c0 - s[0], c1 - s[1], c2 - s[2]
    d = math.sqrt(dx * dx + dy * dy + dz * dz)
    if d + r <= s[3]:
        return
    if s[3] < 0.0 or d + s[3] <= r:
        s[0], s[1], s[2], s[3] = c0, c1, c2, r * (1.0 + PAD)
        return
    nr = 0.5 * (d + s[3] + r)
    t = (nr - s[3]) / d
    s[0] += dx * t
    s[1] += dy * t
    s[2] += dz * t
    s[3] = nr * (1.0 + PAD) + PAD * d


@nb.njit(cache=True, nogil=True, inline="always")
def _angle(a0, a1, a2, b0, b1, b2):
    d = a0 * b0 + a1 * b1 + a2 * b2
    if d > 1.0:
        d = 1.0
    elif d < -1.0:
        d = -1.0
    return math.acos(d)


@nb.njit(cache=True, nogil=True)
def cone_add_cone(c, b0, b1, b2, bt):
    """Grow cone ``c`` (4,) in place to contain cone (b, bt)."""
    if bt < 0.0:
        return
    if c[3] < 0.0:
        c[0], c[1], c[2], c[3] = b0, b1, b2, bt
        return
    if c[3] >= math.pi:
        return
    phi = _angle(c[0], c[1], c[2], b0, b1, b2)
    if phi + bt <= c[3]:
        return
    if phi + c[3] <= bt:
        c[0], c[1], c[2], c[3] = b0, b1, b2, bt
        return
    nt = 0.5 * (phi + c[3] + bt) + 1e-7
    if nt >= math.pi:
        c[3] = math.pi
        return
    # Rotate the axis towards b by (nt - c[3]) within the plane of both axes.
    alpha = nt - c[3]
    d = c[0] * b0 + c[1] * b1 + c[2] * b2
    w0, w1, w2 = b0 - d * c[0], b1 - d * c[1], b2 - d * c[2]
    wl = math.sqrt(w0 * w0 + w1 * w1 + w2 * w2)
    if wl < 1e-12:           # opposite axes: any perpendicular will do
        c[3] = math.pi
        return
    ca, sa = math.cos(alpha), math.sin(alpha)
    a0 = ca * c[0] + sa * w0 / wl
    a1 = ca * c[1] + sa * w1 / wl
    a2 = ca * c[2] + sa * w2 / wl
    al = math.sqrt(a0 * a0 + a1 * a1 + a2 * a2)
    c[0], c[1], c[2], c[3] = a0 / al, a1 / al, a2 / al, nt


@nb.njit(cache=True, nogil=True, inline="always")
def quadric_add_plane(q, n0, n1, n2, d, w):
    """Add ``w`` times the squared distance to plane n.x + d = 0 to ``q``."""
    q[0] += w * n0 * n0
    q[1] += w * n0 * n1
    q[2] += w * n0 * n2
    q[3] += w * n0 * d
    q[4] += w * n1 * n1
    q[5] += w * n1 * n2
    q[6] += w * n1 * d
    q[7] += w * n2 * n2
    q[8] += w * n2 * d
    q[9] += w * d * d


@nb.njit(cache=True, nogil=True, inline="always")
def quadric_eval(q, x, y, z):
    """Quadric error of point (x, y, z)."""
    return (q[0] * x * x + 2.0 * q[1] * x * y + 2.0 * q[2] * x * z + 2.0 * q[3] * x
            + q[4] * y * y + 2.0 * q[5] * y * z + 2.0 * q[6] * y
            + q[7] * z * z + 2.0 * q[8] * z + q[9])


def empty_spheres(n: int) -> np.ndarray:
    s = np.zeros((n, 4))
    s[:, 3] = -1.0
    return s


def empty_cones(n: int) -> np.ndarray:
    c = np.zeros((n, 4))
    c[:, 2] = 1.0
    c[:, 3] = -1.0
    return c
