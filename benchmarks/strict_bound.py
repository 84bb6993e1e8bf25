"""What the strict error bound buys and costs: cameras with it and without, on the same builds.

    python benchmarks/strict_bound.py [--size 256] [--tolerances 0.5 1 2 4] [--flyover-size 708]
                                      [--seconds 20] [--repeats 3]

A camera opened with ``strict_bound=True`` never draws a node beside a
position that was collapsed away before the node was made
(docs/error-bounds.md, "The strict bound"). Two parts:

* **Bounds**: the rough terrain at 192 cells (73k triangles; the case where
  the default cameras' mixes of ages were found) and the built-in smooth
  terrain, rough terrain and range scan at ``--size`` cells; at each
  tolerance, cameras at ``error.py``'s views converge, with and without the
  strict bound. Reported: original -> LOD (every original position in view
  against the drawn triangles) and LOD -> original (18 points of each drawn
  triangle against the original surface) p99 and max as multiples of the
  tolerance, faces a view, the nodes drawn beside a position gone before
  them (:func:`caveclod.refine.measure.mixed_nodes`) and the share of faces
  from splits the node's own test does not ask for
  (:func:`caveclod.refine.measure.forced_splits`).
* **Flyover**: four cameras over each 1M-triangle built-in (``refine.py``'s
  flyovers, 1280x720, 1 px, 30 Hz, the first second left out), the two
  variants one after the other in each repeat: update p50 and p99 per
  camera-frame (medians of the repeats), faces a camera, operations.

Writes ``benchmarks/results/strict_bound.json`` and ``strict_bound.png``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

import caveclod
from caveclod.builder.builtin import rough_terrain
from caveclod.builder.hierarchy import build_static_mesh
from caveclod.refine.measure import (forced_splits, hidden_positions, mixed_nodes, original_triangles, pixel_errors,
                                     surface_errors)

sys.path.insert(0, str(Path(__file__).parent))
from error import views  # noqa: E402
from refine import FPS, RESULTS, compare_flights, load_mesh, views_for  # noqa: E402

CAMERAS = 4
VARIANTS = {"default": {}, "strict": {"strict_bound": True}}


def converged(mesh, view, options, limit=20):
    cam = mesh.new_camera(**options)
    for _ in range(limit):
        if cam.update(view).operations == 0:
            return cam
    raise RuntimeError(f"a camera did not converge in {limit} updates")


def bounds(mesh, tolerance, original, options) -> dict:
    px, back, faces, mixed, forced = [], [], [], 0, []
    for view in views(mesh, tolerance):
        cam = converged(mesh, view, options)
        tris = cam.triangles()
        # Parts hidden for being under the tolerance have nothing drawn to measure against (as error.py).
        px.append(pixel_errors(mesh, tris, view, points=np.asarray(mesh.positions)[~hidden_positions(cam)]))
        back.append(surface_errors(mesh, tris, original, view))
        faces.append(cam.n_faces)
        mixed += len(mixed_nodes(cam))
        forced.append(forced_splits(cam, view)["forced_share"])
    px, back = np.concatenate(px) / tolerance, np.concatenate(back) / tolerance
    return {"original_to_lod_p99": float(np.percentile(px, 99)), "original_to_lod_max": float(px.max()),
            "lod_to_original_p99": float(np.percentile(back, 99)), "lod_to_original_max": float(back.max()),
            "faces_mean": float(np.mean(faces)), "mixed_nodes": int(mixed),
            "forced_share_median": float(np.median(forced)), "forced_share_max": float(np.max(forced))}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", type=int, default=256, help="cells per side of the built-ins measured for bounds")
    ap.add_argument("--tolerances", type=float, nargs="+", default=[0.5, 1.0, 2.0, 4.0])
    ap.add_argument("--flyover-size", type=int, default=708, help="cells per side of the flyovers' terrains "
                    "(708 = 1.0M triangles; 0 skips the flyovers)")
    ap.add_argument("--seconds", type=float, default=20.0, help="flyover length")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--out", type=Path, default=RESULTS / "strict_bound.json")
    args = ap.parse_args(argv)
    report = {"size": args.size, "tolerances": args.tolerances, "bounds": {}, "flyover": {}}
    cases = [("rough 192", lambda: build_static_mesh(rough_terrain(192)))]
    cases += [(f"{name} {args.size}", lambda name=name: caveclod.build(name, size=args.size))
              for name in ("default", "rough", "scan")]
    for label, make in cases:
        t0 = time.perf_counter()
        mesh = make()
        original = original_triangles(mesh)
        rows = {}
        for tol in args.tolerances:
            rows[str(tol)] = {k: bounds(mesh, tol, original, o) for k, o in VARIANTS.items()}
            d, s = rows[str(tol)]["default"], rows[str(tol)]["strict"]
            print(f"{label:12s} {tol:4.1f} px: original->LOD max {d['original_to_lod_max']:.3f} -> "
                  f"{s['original_to_lod_max']:.3f} t (p99 {d['original_to_lod_p99']:.3f} -> "
                  f"{s['original_to_lod_p99']:.3f}); LOD->original max {d['lod_to_original_max']:.3f} -> "
                  f"{s['lod_to_original_max']:.3f} t; faces {d['faces_mean']:,.0f} -> {s['faces_mean']:,.0f} "
                  f"({s['faces_mean'] / d['faces_mean'] - 1:+.1%}); mixed nodes {d['mixed_nodes']} -> "
                  f"{s['mixed_nodes']}; forced share {d['forced_share_median']:.1%} -> "
                  f"{s['forced_share_median']:.1%}", flush=True)
        report["bounds"][label] = {"faces": mesh.n_faces, "seconds": round(time.perf_counter() - t0, 1),
                                   "tolerances": rows}
    if args.flyover_size:
        for name in ("default", "rough"):
            mesh, label = load_mesh(name, args.flyover_size)
            lo, hi = mesh.bounds()
            views_ = views_for(lo, hi, CAMERAS, int(args.seconds * FPS), 1.0)
            variants = {k: (mesh, o) for k, o in VARIANTS.items()}
            report["flyover"][name] = {"mesh": label, **compare_flights(variants, views_, args.repeats, label)}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(report, indent=1))
    _plot(report, args.out.with_suffix(".png"))
    return 0


def _plot(report: dict, path: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    cases = list(report["bounds"])
    tols = [str(t) for t in report["tolerances"]]
    fig, axes = plt.subplots(1, 2, figsize=(11, 3.8))
    for i, label in enumerate(cases):
        rows = report["bounds"][label]["tolerances"]
        for k, ls in (("default", ":"), ("strict", "-")):
            axes[0].plot([float(t) for t in tols], [rows[t][k]["original_to_lod_max"] for t in tols], ls=ls,
                         marker="o", color=f"C{i}", label=f"{label}, {k}")
        axes[1].plot([float(t) for t in tols],
                     [rows[t]["strict"]["faces_mean"] / rows[t]["default"]["faces_mean"] for t in tols],
                     marker="o", color=f"C{i}", label=label)
    axes[0].axhline(1.0, color="k", lw=1, ls="--")
    axes[0].set_xscale("log", base=2)
    axes[0].set_xlabel("tolerance, px")
    axes[0].set_ylabel("original -> LOD max / tolerance")
    axes[0].legend(fontsize=6)
    axes[1].set_xscale("log", base=2)
    axes[1].set_xlabel("tolerance, px")
    axes[1].set_ylabel("faces, strict / default")
    axes[1].legend(fontsize=7)
    fig.suptitle("the strict bound: the largest error drawn, and what it costs in faces")
    fig.tight_layout()
    fig.savefig(path, dpi=110)


if __name__ == "__main__":
    raise SystemExit(main())
