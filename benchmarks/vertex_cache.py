"""Keyframes in vertex-cache order: ACMR of the buffers a keyframe sends, before and after.

Four cameras fly the flyover over the 1M-triangle default terrain (640x360
each, 1 px); every ``--every`` frames each camera's index buffers are taken
as a keyframe would send them: in the slot order refinement left (what
caveclod sent before), reordered by caveclod (Tipsify,
``CameraState.reorder_for_vertex_cache``, what a keyframe sends now), and
reordered by meshoptimizer's ``optimizeVertexCache`` (the reference). ACMR
is vertices transformed per triangle through a 16-entry FIFO cache (0.5 is
a regular grid's floor). Also the time a reorder takes.

    .venv/bin/python benchmarks/vertex_cache.py [--size 708] [--frames 200] [--every 20]

Writes benchmarks/results/vertex_cache.json and vertex_cache.png.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from service import RESULTS, mesh_path  # noqa: E402


def meshopt_order(buf: np.ndarray) -> np.ndarray:
    import meshoptimizer
    out = np.empty(buf.size, np.uint32)
    meshoptimizer.optimize_vertex_cache(out, np.ascontiguousarray(buf, np.uint32).ravel(), buf.size, int(buf.max()) + 1)
    return out.reshape(-1, 3)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--size", type=int, default=708)
    ap.add_argument("--frames", type=int, default=200)
    ap.add_argument("--every", type=int, default=20)
    args = ap.parse_args()
    import caveclod
    from caveclod.kernels.cacheorder import acmr, cache_order
    from caveclod.paths import pose
    mesh = caveclod.load(mesh_path(args.size))
    lo, hi = mesh.bounds()
    cams = [mesh.new_camera() for _ in range(4)]
    rows = []
    for f in range(args.frames):
        for c, cam in enumerate(cams):
            p = pose("flyover", lo, hi, c, f / 30)
            cam.update(caveclod.View(eye=p.eye, target=p.target, up=p.up, width=640, height=360, tolerance_px=1.0))
        if f % args.every != args.every - 1:
            continue
        for c, cam in enumerate(cams):
            for m in range(cam.n_materials):
                if cam.cnt[m] < 100:
                    continue
                # The cameras are never reordered here, so that each keyframe starts from the
                # order refinement leaves (a session's camera keeps a keyframe's order until
                # splits and collapses wear it down).
                slot = cam.index_buffer(m).copy()
                theirs = acmr(meshopt_order(slot))
                t0 = time.perf_counter()
                order = cache_order(slot)
                ms = 1000 * (time.perf_counter() - t0)
                ours = acmr(slot[order])
                rows.append({"frame": f, "camera": c, "material": m, "triangles": len(slot), "acmr_slot_order": acmr(slot),
                             "acmr_caveclod": ours, "acmr_meshoptimizer": theirs, "order_ms": ms})
    if not rows:
        print("no buffer of 100 triangles or more was seen", file=sys.stderr)
        return 1

    def median(key):
        return round(statistics.median(r[key] for r in rows), 3)
    ratios = [r["acmr_caveclod"] / r["acmr_meshoptimizer"] for r in rows]
    total = sum(r["triangles"] for r in rows)

    def overall(key):                       # every keyframe buffer together: vertices per triangle
        return round(sum(r[key] * r["triangles"] for r in rows) / total, 3)
    summary = {"buffers": len(rows), "median_triangles": median("triangles"),
               "overall_acmr_slot_order": overall("acmr_slot_order"), "overall_acmr_caveclod": overall("acmr_caveclod"),
               "overall_acmr_meshoptimizer": overall("acmr_meshoptimizer"),
               "acmr_slot_order": median("acmr_slot_order"), "acmr_caveclod": median("acmr_caveclod"),
               "acmr_meshoptimizer": median("acmr_meshoptimizer"),
               "ratio_to_meshoptimizer_median": round(statistics.median(ratios), 3),
               "ratio_to_meshoptimizer_max": round(max(ratios), 3),
               "order_us_per_1000_triangles": round(statistics.median(1000 * r["order_ms"] / r["triangles"] * 1000
                                                                        for r in rows), 1)}
    print(json.dumps(summary))
    RESULTS.mkdir(parents=True, exist_ok=True)
    out = {"mesh": f"default_{args.size}", "frames": args.frames, "every": args.every, "cache": "FIFO 16",
           "summary": summary, "rows": rows}
    (RESULTS / "vertex_cache.json").write_text(json.dumps(out, indent=1) + "\n")
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(7, 3.8))
    for key, label in (("acmr_slot_order", "slot order (before)"), ("acmr_caveclod", "caveclod (Tipsify)"),
                       ("acmr_meshoptimizer", "meshoptimizer")):
        ax.scatter([r["triangles"] for r in rows], [r[key] for r in rows], s=10, label=label)
    ax.set_xscale("log")
    ax.set_xlabel("triangles in the buffer")
    ax.set_ylabel("ACMR (FIFO 16)")
    ax.set_title("keyframe buffers of a 4-camera flyover, 1M-triangle terrain")
    ax.legend()
    fig.tight_layout()
    fig.savefig(RESULTS / "vertex_cache.png", dpi=110)
    print(f"wrote {RESULTS / 'vertex_cache.json'} and vertex_cache.png")
    return 0


if __name__ == "__main__":
    sys.exit(main())
