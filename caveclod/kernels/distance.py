"""Exact Euclidean distances from points to triangles and segments.

Used by the build (the error bound of a node is the largest distance from
the original positions its collapse disturbed to the new local surface) and
by the renderer-free screen-space error measurement. Closest points follow
the Voronoi-region case analysis of Ericson, *Real-Time Collision Detection*
(2005), section 5.1.5, written out for scalars so that numba keeps it in
registers.
"""

import numba as nb

# Plain njit, not inline="always": these take scalars only (nothing to
# reference-count), and LLVM inlines them at every call site anyway (the
# collapse kernels' machine code calls neither). numba's own inlining copied
# them into the carried points' re-measure at ten sites: 49 of the 83 s a
# fresh checkout took to finish its first (tiny) build; 30 s now.


@nb.njit(cache=True, nogil=True)
def point_segment_dist2(px, py, pz, ax, ay, az, bx, by, bz):
    """Squared distance from point p to the segment a-b (a point if a == b)."""
    abx, aby, abz = bx - ax, by - ay, bz - az
    apx, apy, apz = px - ax, py - ay, pz - az
    den = abx * abx + aby * aby + abz * abz
    t = 0.0
    if den > 0.0:
        t = (apx * abx + apy * aby + apz * abz) / den
        if t < 0.0:
            t = 0.0
        elif t > 1.0:
            t = 1.0
    dx, dy, dz = apx - t * abx, apy - t * aby, apz - t * abz
    return dx * dx + dy * dy + dz * dz


@nb.njit(cache=True, nogil=True)
def point_triangle_dist2(px, py, pz, ax, ay, az, bx, by, bz, cx, cy, cz):
    """Squared distance from point p to the (solid) triangle a, b, c.

    Degenerate triangles (zero area) fall back to the nearest of the three
    edges, so slivers are measured as the segments they are.
    """
    abx, aby, abz = bx - ax, by - ay, bz - az
    acx, acy, acz = cx - ax, cy - ay, cz - az
    apx, apy, apz = px - ax, py - ay, pz - az
    d1 = abx * apx + aby * apy + abz * apz
    d2 = acx * apx + acy * apy + acz * apz
    if d1 <= 0.0 and d2 <= 0.0:                          # vertex region a
        return apx * apx + apy * apy + apz * apz
    bpx, bpy, bpz = px - bx, py - by, pz - bz
    d3 = abx * bpx + aby * bpy + abz * bpz
    d4 = acx * bpx + acy * bpy + acz * bpz
    if d3 >= 0.0 and d4 <= d3:                           # vertex region b
        return bpx * bpx + bpy * bpy + bpz * bpz
    cpx, cpy, cpz = px - cx, py - cy, pz - cz
    d5 = abx * cpx + aby * cpy + abz * cpz
    d6 = acx * cpx + acy * cpy + acz * cpz
    if d6 >= 0.0 and d5 <= d6:                           # vertex region c
        return cpx * cpx + cpy * cpy + cpz * cpz
    vc = d1 * d4 - d3 * d2
    vb = d5 * d2 - d1 * d6
    va = d3 * d6 - d5 * d4
    den = va + vb + vc
    if den <= 0.0 or not (den == den):
        # Zero area: the closest point lies on one of the edges.
        e1 = point_segment_dist2(px, py, pz, ax, ay, az, bx, by, bz)
        e2 = point_segment_dist2(px, py, pz, bx, by, bz, cx, cy, cz)
        e3 = point_segment_dist2(px, py, pz, cx, cy, cz, ax, ay, az)
        return min(e1, min(e2, e3))
    if vc <= 0.0 and d1 >= 0.0 and d3 <= 0.0:            # edge region ab
        return point_segment_dist2(px, py, pz, ax, ay, az, bx, by, bz)
    if vb <= 0.0 and d2 >= 0.0 and d6 <= 0.0:            # edge region ac
        return point_segment_dist2(px, py, pz, ax, ay, az, cx, cy, cz)
    if va <= 0.0 and (d4 - d3) >= 0.0 and (d5 - d6) >= 0.0:   # edge region bc
        return point_segment_dist2(px, py, pz, bx, by, bz, cx, cy, cz)
    v = vb / den                                         # inside: project on the plane
    w = vc / den
    qx = ax + abx * v + acx * w - px
    qy = ay + aby * v + acy * w - py
    qz = az + abz * v + acz * w - pz
    return qx * qx + qy * qy + qz * qz
