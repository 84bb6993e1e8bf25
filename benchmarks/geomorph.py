"""Popping, renderer-free: how far the drawn surface jumps from one frame to the next, with and
without geomorphs.

Four cameras fly the flyover over the 1M-triangle terrains at 30 Hz, 4 px,
1280x720, 60 degrees, each refined once a frame (as the service does: the
first refinement is the session's keyframe, not morphed), for ``--frames``
frames after a 2 s settle. For every frame the drawn surface
(the camera's triangles over the vertices where :class:`caveclod.client.
geomorph.Geomorphs` draws them at that instant: growing vertices on their
way from their target) is compared with the previous frame's: seven points
inside every triangle that is new or has a moving vertex are measured
against the other surface (the BVH of :mod:`caveclod.kernels.nearest`),
both ways, and converted to pixels at their distance from the eye as the
screen-space test converts errors; points outside the view are left out.
A frame's jump is its largest such distance. Reported per terrain and morph
duration (0: no morphs, what caveclod drew before): p50, p99 and max of the
per-frame jumps over all cameras, and the share of frames over 0.25 px.
``--speeds``: also morphs timed by their path on screen at these pixels a
second (each at most ``--longest`` ms), with how long they took.

Camera motion is not a jump (the surfaces are compared in world space);
a morphing vertex moves a little every frame, a popping one all at once.

    .venv/bin/python benchmarks/geomorph.py [--size 708] [--frames 300] [--durations 0 250 500 1000]
                                            [--speeds PX ...] [--longest 8000] [--out F]

Writes benchmarks/results/geomorph.json (or ``--out``) and a .png beside it.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from vertex_download import built, screen_factors  # noqa: E402

from service import RESULTS  # noqa: E402

CAMERAS, FPS, TOLERANCE = 4, 30.0, 4.0
SETTLE_FRAMES = 60
SAMPLES = np.array([[1, 1, 1], [4, 1, 1], [1, 4, 1], [1, 1, 4], [2, 2, 1], [2, 1, 2], [1, 2, 2]], np.float64)
SAMPLES /= SAMPLES.sum(axis=1, keepdims=True)


class _Surface:
    """One material's writes, as :class:`Geomorphs` reads them."""

    def __init__(self, material, delta):
        self.material, self.count, self.slots, self.tris = material, delta.count, delta.slots, delta.tris


def drawn(cam, morphs, positions: np.ndarray, now: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(V (d, 3) float64 drawn positions, T (k, 3) int64 drawn triangles, moving (d,) bool)."""
    moving = np.zeros(len(positions), bool)
    if morphs is None:
        tris = [np.asarray(t, np.int64).reshape(-1, 3) for t in cam.triangles().values()]
        return positions, np.concatenate(tris or [np.zeros((0, 3), np.int64)]), moving
    tris = np.concatenate([morphs.display(m).astype(np.int64) for m in range(cam.n_materials)])
    moving[morphs._vertices(list(morphs.active))] = True
    return morphs.drawn_positions(now), tris, moving


def one_way(V_a, T_a, changed_a, V_b, T_b, view) -> float:
    """Largest pixel distance from sample points of ``T_a``'s changed triangles to surface b."""
    from caveclod.kernels.nearest import build_bvh, nearest_dist2
    if not changed_a.any() or not len(T_b):
        return 0.0
    pts = np.einsum("sc,kcd->ksd", SAMPLES, V_a[T_a[changed_a]]).reshape(-1, 3)
    f = screen_factors(view, pts)
    pts, f = pts[f > 0], f[f > 0]
    if not len(pts):
        return 0.0
    d2 = nearest_dist2(pts, V_b, T_b, *build_bvh(V_b, T_b))
    return float((np.sqrt(d2) * f).max())


def frame_jump(prev, cur, view) -> float:
    """The surface's jump between two drawn states ``(V, T, moving)``, in pixels (both ways)."""
    V0, T0, m0 = prev
    V1, T1, m1 = cur
    key0 = set(map(tuple, np.sort(T0, axis=1).tolist()))
    key1 = set(map(tuple, np.sort(T1, axis=1).tolist()))
    new1 = np.array([tuple(t) not in key0 for t in np.sort(T1, axis=1).tolist()], bool).reshape(-1)
    gone0 = np.array([tuple(t) not in key1 for t in np.sort(T0, axis=1).tolist()], bool).reshape(-1)
    moved = m0 | m1
    ch1 = new1 | (moved[T1].any(axis=1) if len(T1) else np.zeros(0, bool))
    ch0 = gone0 | (moved[T0].any(axis=1) if len(T0) else np.zeros(0, bool))
    return max(one_way(V1, T1, ch1, V0, T0, view), one_way(V0, T0, ch0, V1, T1, view))


def fly(mesh, targets, duration_ms: float, frames: int, speed: float | None = None) -> tuple[list, list, list]:
    """(per-frame jumps (px), per-frame client milliseconds of the geomorphs, seconds each morph took)
    of every camera over the flyover; with ``speed`` (pixels a second) morphs last their path on
    screen over it, at most ``duration_ms``."""
    import caveclod
    from caveclod.client.geomorph import Geomorphs, pixels_per_unit, points_of
    from caveclod.paths import flyover
    lo, hi = mesh.bounds()
    points = points_of(mesh.vertex_positions, targets)
    positions = np.asarray(mesh.vertex_positions, np.float64)
    jumps, cost, spans = [], [], []
    for c in range(CAMERAS):
        cam = mesh.new_camera()
        morphs = Geomorphs(mesh.vertex_positions, targets, cam.n_materials, duration_ms / 1000,
                           points, speed=speed) if duration_ms > 0 else None
        # The session's frame 1: a keyframe refined for the first pose (not morphed).
        cam.update(caveclod.View.from_pose(flyover(lo, hi, c, 3.0 * c), tolerance_px=TOLERANCE))
        if morphs is not None:
            first = [_Surface(m, type("K", (), {"count": cam.cnt[m], "slots": np.arange(cam.cnt[m]),
                                                "tris": cam.index_buffer(m)})) for m in range(cam.n_materials)]
            morphs.apply(first, True, 0.0)
        prev = None
        for f in range(SETTLE_FRAMES + frames):
            now = f / FPS
            view = caveclod.View.from_pose(flyover(lo, hi, c, 3.0 * c + now), tolerance_px=TOLERANCE)
            delta = cam.update(view)
            if morphs is not None:           # what a client does a frame: end morphs, apply, move
                t0 = time.perf_counter()
                morphs.tick(now)
                morphs.look_from(view.eye, pixels_per_unit(view.height, view.fov_y))
                morphs.apply([_Surface(m, d) for m, d in delta.surfaces.items()], False, now)
                morphs.moving(now)
                if f >= SETTLE_FRAMES:
                    cost.append(1000 * (time.perf_counter() - t0))
                    spans.extend(m.span for m in morphs.active.values() if m.t0 == now)
            cur = drawn(cam, morphs, positions, now)
            if prev is not None and f >= SETTLE_FRAMES:
                jumps.append(frame_jump(prev, cur, view))
            prev = cur
    return jumps, cost, spans


def summary(jumps: list) -> dict:
    j = np.asarray(jumps)
    return {"frames": len(j), "p50_px": round(float(np.percentile(j, 50)), 4),
            "p99_px": round(float(np.percentile(j, 99)), 4), "max_px": round(float(j.max()), 4),
            "over_0_25_px": round(float((j > 0.25).mean()), 4)}


def plot(results: list, out: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(7, 4))
    for r in results:
        j = np.sort(np.asarray(r["jumps_px"]))
        ax.semilogx(np.maximum(j, 1e-4), np.linspace(0, 1, len(j)),
                    label=f"{r['mesh']}, " + ("no morphs" if r['morph_ms'] == 0 else f"{r['morph_ms']:g} ms"
                                              if r.get('morph_px_s') is None else f"{r['morph_px_s']:g} px/s"))
    ax.axvline(0.25, ls=":", c="k")
    ax.set(xlabel="per-frame jump of the drawn surface, px", ylabel="share of frames",
           title=f"popping on the flyover at {TOLERANCE:g} px, {CAMERAS} cameras")
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(out, dpi=110)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--size", type=int, default=708)
    ap.add_argument("--frames", type=int, default=300)
    ap.add_argument("--durations", type=float, nargs="*", default=[0, 250, 500, 1000], help="morph ms (0: none)")
    ap.add_argument("--speeds", type=float, nargs="*", default=[],
                    help="also morphs at these pixels a second (each at most --longest ms)")
    ap.add_argument("--longest", type=float, default=8000, help="the longest a morph at a speed takes, ms")
    ap.add_argument("--meshes", nargs="+", default=["default", "rough"])
    ap.add_argument("--out", type=Path, default=RESULTS / "geomorph.json", help="the JSON to write (and a .png beside)")
    args = ap.parse_args()
    import caveclod
    from caveclod.refine.morphtargets import morph_targets
    results = []
    for name in args.meshes:
        mesh = caveclod.load(built(name, args.size))
        targets = morph_targets(mesh)
        for ms, speed in [(ms, None) for ms in args.durations] + [(args.longest, v) for v in args.speeds]:
            t0 = time.perf_counter()
            jumps, cost, spans = fly(mesh, targets, ms, args.frames, speed)
            row = {"mesh": name, "size": args.size, "morph_ms": ms, "morph_px_s": speed, **summary(jumps),
                   "morph_seconds": {"p50": round(float(np.percentile(spans, 50)), 3),
                                     "p99": round(float(np.percentile(spans, 99)), 3)} if spans else None,
                   "client_ms_per_camera_frame": {"p50": round(float(np.percentile(cost, 50)), 3),
                                                  "p99": round(float(np.percentile(cost, 99)), 3)} if cost else None,
                   "seconds": round(time.perf_counter() - t0, 1), "jumps_px": [round(x, 5) for x in jumps]}
            results.append(row)
            how = f"{ms:6.0f} ms" if speed is None else \
                f"{speed:g} px/s (<= {ms:.0f} ms, took {row['morph_seconds']} s)"
            print(f"{name:8s} morph {how}: jump p50 {row['p50_px']:.3f} p99 {row['p99_px']:.3f} "
                  f"max {row['max_px']:.3f} px, {100 * row['over_0_25_px']:.1f} % of frames over 0.25 px; "
                  f"client {row['client_ms_per_camera_frame']} ms a camera-frame",
                  file=sys.stderr)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps({"tolerance_px": TOLERANCE, "cameras": CAMERAS, "fps": FPS, "results": results},
                                   indent=1))
    plot(results, args.out.with_suffix(".png"))
    return 0


if __name__ == "__main__":
    sys.exit(main())
