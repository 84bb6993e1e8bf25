"""The screen-space error a camera really shows, renderer-free.

    python benchmarks/error.py [--size 256] [--tolerances 0.5 1 2 4] [--baseline DIR]

For the smooth default terrain, the rough terrain (fractal relief, no-data
holes) and a range scan (open border, holes, a cut-up UV atlas), cameras at
several views (the paper's flyovers and the cache paper's circle, rotation
and line paths; an orbit for the scan) refine until they converge at each
tolerance. Then every original position in view is measured against the
triangles the camera draws (:func:`caveclod.refine.measure.pixel_errors`)
and converted to pixels as the screen-space test converts errors.

Reported per mesh and tolerance: the distribution (p50, p90, p99, p99.9,
max, in pixels and as a multiple of the tolerance), the positions measured
and the faces drawn. The other direction too (``lod_to_original``): 18
points of each drawn triangle measured against the original surface
(:func:`caveclod.refine.measure.surface_errors`; a sample, so its max is a
lower bound), the bulge of the LOD surface between original positions.

``--baseline DIR`` builds the same meshes with the checkout in DIR (a child
process there writes ``.cvc`` files) and measures them here, with this
checkout's refinement and measure, beside this checkout's builds: how a
change of the build moves the bounds and the faces drawn. Writes
``benchmarks/results/error.json`` and ``error.png`` (the distributions as
CDFs, both directions).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

import caveclod
from caveclod.paths import circle, flyover, line, rotate
from caveclod.refine.measure import hidden_positions, original_triangles, pixel_errors, surface_errors

RESULTS = Path(__file__).parent / "results"
MESHES = ("default", "rough", "scan")


def views(mesh, tolerance):
    lo, hi = mesh.bounds()
    ext = hi - lo
    if ext[2] < max(ext[0], ext[1]) / 3:
        poses = [flyover(lo, hi, c, 3.0 * c) for c in range(4)]
        poses += [circle(lo, hi, 0, 5.0), rotate(lo, hi, 1, 2.0), line(lo, hi, 2, 7.0)]
    else:
        c = (lo + hi) / 2
        r = float(np.linalg.norm(ext))
        poses = []
        for k in range(7):
            angle = 0.7 + 0.9 * k
            eye = c + r * (0.4 + 0.3 * k) * np.array([math.cos(angle), math.sin(angle), 0.2 * (k - 3)])
            poses.append((tuple(eye), tuple(c), (0.0, 0.0, 1.0)))
    return [caveclod.View.from_pose(p, tolerance_px=tolerance) for p in poses]


def measure(mesh, tolerance, original):
    px, back, faces = [], [], []
    for view in views(mesh, tolerance):
        cam = mesh.new_camera()
        for _ in range(6):
            if cam.update(view).operations == 0:
                break
        # Parts hidden for being small have nothing drawn to measure against (docs/parts.md):
        # the positions of the parts drawn are measured.
        px.append(pixel_errors(mesh, cam.triangles(), view, points=np.asarray(mesh.positions)[~hidden_positions(cam)]))
        back.append(surface_errors(mesh, cam.triangles(), original, view))
        faces.append(cam.n_faces)
    return np.concatenate(px), np.concatenate(back), faces


def distribution(px: np.ndarray, tolerance: float) -> dict:
    q = np.percentile(px, [50, 90, 99, 99.9])
    return {"p50": float(q[0]), "p90": float(q[1]), "p99": float(q[2]), "p999": float(q[3]), "max": float(px.max()),
            "p99_over_tolerance": float(q[2] / tolerance), "max_over_tolerance": float(px.max() / tolerance)}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", type=int, default=256, help="cells (samples) per side of each built-in")
    ap.add_argument("--tolerances", type=float, nargs="+", default=[0.5, 1.0, 2.0, 4.0])
    ap.add_argument("--baseline", type=Path, help="a checkout whose build to measure beside this one's")
    ap.add_argument("--out", type=Path, default=RESULTS / "error.json")
    args = ap.parse_args(argv)
    report = {"size": args.size, "meshes": {}}
    builds = {"this": None} if args.baseline is None else {"this": None, "baseline": args.baseline.resolve()}
    curves = {}
    with tempfile.TemporaryDirectory() as tmp:
        for name in MESHES:
            for label, checkout in builds.items():
                t0 = time.perf_counter()
                mesh = caveclod.build(name, size=args.size) if checkout is None else \
                    _build_in(checkout, name, args.size, Path(tmp) / f"{name}.cvc")
                original = original_triangles(mesh)
                rows = {}
                for tol in args.tolerances:
                    px, back, faces = measure(mesh, tol, original)
                    rows[str(tol)] = {"positions_measured": int(len(px)), "faces_drawn": faces,
                                      **distribution(px, tol),
                                      "lod_to_original": {"points_measured": int(len(back)), **distribution(back, tol)}}
                    curves[(label, name, tol)] = (np.sort(px), np.sort(back))
                    d, b = rows[str(tol)], rows[str(tol)]["lod_to_original"]
                    print(f"{label:8s} {name:8s} {tol:4.1f} px: original->LOD p50 {d['p50']:.3f}  p99 {d['p99']:.3f}  "
                          f"max {d['max']:.3f} px ({d['max_over_tolerance']:.2f} x) over {len(px):,} positions; "
                          f"LOD->original p99 {b['p99']:.3f}  max {b['max']:.3f} px ({b['max_over_tolerance']:.2f} x) "
                          f"over {len(back):,} points; {int(np.mean(faces)):,} faces a view", flush=True)
                entry = {"faces": mesh.n_faces, "base_faces": len(mesh.base_faces),
                         "seconds": round(time.perf_counter() - t0, 1), "tolerances": rows}
                if label == "this":
                    report["meshes"][name] = entry
                else:
                    report.setdefault("baseline", {"checkout": str(checkout), "meshes": {}})["meshes"][name] = entry
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(report, indent=1))
    _plot(curves, args.tolerances, list(builds), args.out.with_suffix(".png"))
    return 0


def _build_in(checkout: Path, name: str, size: int, path: Path):
    """Build a built-in with the caveclod of another checkout; the mesh loaded here."""
    code = f"import caveclod; caveclod.build({name!r}, size={size}).save({str(path)!r})"
    env = {**os.environ, "PYTHONPATH": str(checkout)}
    subprocess.run([sys.executable, "-c", code], cwd=checkout, env=env, check=True)
    return caveclod.load(path)


def _plot(curves, tolerances, labels, path: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(2, len(MESHES), figsize=(4 * len(MESHES), 6.6), sharey=True, squeeze=False)
    for col, name in enumerate(MESHES):
        for row, direction in enumerate(("original -> LOD", "LOD -> original")):
            ax = axes[row, col]
            for i, tol in enumerate(tolerances):
                for label in labels:
                    x = curves[(label, name, tol)][row] / tol
                    ax.plot(x, np.linspace(0, 1, len(x)), color=f"C{i}", ls="-" if label == "this" else ":",
                            label=f"{tol:g} px" + ("" if label == "this" else f" ({label})"))
            ax.axvline(1.0, color="k", lw=1, ls="--")
            ax.set_xlim(0, 2.0)
            ax.set_title(f"{name}: {direction}")
            ax.set_xlabel("error / tolerance")
    for row in range(2):
        axes[row, 0].set_ylabel("fraction of points in view")
    axes[0, 0].legend(title="tolerance", fontsize=7)
    fig.suptitle("renderer-free screen-space error of converged cameras")
    fig.tight_layout()
    fig.savefig(path, dpi=100)


if __name__ == "__main__":
    sys.exit(main())
