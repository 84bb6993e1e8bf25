"""Parts that vanish: a field of 5,120 small parts from near to afar, with and without pruning.

    .venv/bin/python benchmarks/parts.py [--size 256] [--terrain-size 708]

The built-in debris field (``caveclod build debris``: 20 x --size parts,
boulders, blocks and sheets) at 1280x720, seen from the south and above at
distances where the field spans from 2,560 down to 10 pixels. At each
distance and tolerance (1 and 4 px) two cameras converge, one hiding parts
smaller than the tolerance (``View(prune=True)``, the default) and one not:

* ``faces`` drawn by each, and ``hidden`` parts;
* ``hidden_max_px``: the largest hidden part measured from its own original
  positions (:func:`caveclod.refine.measure.hidden_part_pixels`); pruning
  promises less than the tolerance;
* ``bound_p99_px`` / ``bound_max_px``: the vertex bound of what is drawn
  (every original position of the visible parts against the drawn
  triangles, :func:`caveclod.refine.measure.pixel_errors`);
* ``update_us``: median of 20 updates of the converged camera at rest.

Then a dolly from afar to near and back (300 frames) with and without
pruning (medians of 3 runs): update time p50/p99 and the parts shown and hidden; and the cost of
the part test on a one-part mesh: the 1M default terrain's 4-camera flyover
(10 s at 30 Hz) with pruning on and off, update p50/p99.

Issue 18's target: the field seen from afar draws at most max(1 % of its
faces, 300) with the bound held.

Writes benchmarks/results/parts.json and parts.png.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from refine import RESULTS, load_mesh  # noqa: E402

SPANS = (2560, 1280, 640, 320, 160, 80, 40, 20, 10)      # pixels the field spans across the screen


def _converge(cam, view, limit: int = 100) -> None:
    for _ in range(limit):
        if not cam.update(view).operations:
            return
    raise RuntimeError("no convergence")


def _view_at(mesh, span: float, tolerance: float):
    """The field seen so that its x extent spans ``span`` pixels of a 1280x720 view."""
    import caveclod
    lo, hi = mesh.bounds()
    centre = (lo + hi) / 2
    kappa = 720 / (2 * np.tan(np.radians(30.0)))
    distance = (hi[0] - lo[0]) * kappa / span
    direction = np.array([0.0, -0.8, 0.6])
    return caveclod.View(eye=tuple(centre + distance * direction), target=tuple(centre), up=(0.0, 0.0, 1.0),
                         width=1280, height=720, tolerance_px=tolerance), distance


def at_rest(mesh, span: float, tolerance: float) -> dict:
    from caveclod.refine.measure import hidden_part_pixels, hidden_positions, pixel_errors
    view, distance = _view_at(mesh, span, tolerance)
    row = {"span_px": span, "tolerance_px": tolerance, "distance": round(float(distance), 1)}
    for prune in (True, False):
        v = dataclasses.replace(view, prune=prune)
        cam = mesh.new_camera()
        _converge(cam, v)
        times = []
        for _ in range(20):
            times.append(cam.update(v).seconds)
        hidden = hidden_positions(cam)
        px = pixel_errors(mesh, cam.triangles(), v, points=np.asarray(mesh.positions)[~hidden])
        key = "prune" if prune else "no_prune"
        row[key] = {"faces": cam.n_faces, "hidden": cam.hidden_parts,
                    "hidden_max_px": round(float(hidden_part_pixels(cam, v).max(initial=0.0)), 4),
                    "bound_p99_px": round(float(np.percentile(px, 99)), 4) if len(px) else 0.0,
                    "bound_max_px": round(float(px.max()), 4) if len(px) else 0.0,
                    "update_us": round(1e6 * statistics.median(times), 1), "camera_bytes": cam.nbytes}
    return row


def dolly(mesh, tolerance: float, frames: int = 300, repeats: int = 3) -> dict:
    """From the farthest span to the nearest and back; update p50/p99 with and without pruning
    (each the median of ``repeats`` runs, the two kinds interleaved: this machine is noisy)."""
    far, d_far = _view_at(mesh, SPANS[-1], tolerance)
    _, d_near = _view_at(mesh, SPANS[0], tolerance)
    centre = np.array(far.target)
    direction = (np.array(far.eye) - centre) / d_far
    runs = {True: [], False: []}
    for _ in range(repeats):
        for prune in (True, False):
            cam = mesh.new_camera()
            secs, shown, hidden = [], 0, 0
            for f in range(frames):
                t = 1 - abs(1 - 2 * f / (frames - 1))               # 0 -> 1 -> 0
                distance = d_far * (d_near / d_far) ** (t * t * (3 - 2 * t))   # geometric: even in log distance
                d = cam.update(dataclasses.replace(far, eye=tuple(centre + distance * direction), prune=prune))
                secs.append(d.seconds)
                shown += d.parts_shown
                hidden += d.parts_hidden
            runs[prune].append((np.percentile(secs, 50), np.percentile(secs, 99), shown, hidden))
    out = {}
    for prune, rows in runs.items():
        out["prune" if prune else "no_prune"] = {
            "update_p50_us": round(1e6 * statistics.median(r[0] for r in rows), 1),
            "update_p99_us": round(1e6 * statistics.median(r[1] for r in rows), 1),
            "parts_shown": rows[0][2], "parts_hidden": rows[0][3]}
    return out


def terrain_flyover(mesh, seconds: float = 10.0) -> dict:
    """The part test's cost on a one-part mesh: 4-camera flyover, pruning on and off, interleaved."""
    import caveclod
    from caveclod.paths import flyover
    lo, hi = mesh.bounds()
    out = {}
    cams = {p: [mesh.new_camera() for _ in range(4)] for p in (True, False)}
    secs = {True: [], False: []}
    for f in range(int(seconds * 30)):
        for c in range(4):
            view = caveclod.View.from_pose(flyover(lo, hi, c, f / 30), tolerance_px=1.0)
            for p in ((True, False) if f % 2 else (False, True)):        # alternate who goes first
                secs[p].append(cams[p][c].update(dataclasses.replace(view, prune=p)).seconds)
    for p in (True, False):
        out["prune" if p else "no_prune"] = {"update_p50_us": round(1e6 * float(np.percentile(secs[p], 50)), 1),
                                             "update_p99_us": round(1e6 * float(np.percentile(secs[p], 99)), 1)}
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--size", type=int, default=256, help="debris field size: 20 x size parts")
    ap.add_argument("--terrain-size", type=int, default=708, help="the default terrain for the overhead run")
    args = ap.parse_args()
    import caveclod
    from caveclod.builder.version import made_by_this_code
    path = RESULTS / f"debris_{args.size}.cvc"
    t0 = time.perf_counter()
    if not made_by_this_code(path):           # absent, or built by other code: build it again
        RESULTS.mkdir(parents=True, exist_ok=True)
        caveclod.build("debris", size=args.size).save(path)
    mesh = caveclod.load(path)
    t1 = time.perf_counter()
    parts = mesh.parts()
    out = {"size": args.size, "parts": parts.count, "faces": mesh.n_faces, "base_faces": len(mesh.base_faces),
           "parts_seconds": round(time.perf_counter() - t1, 3), "build_or_load_seconds": round(t1 - t0, 1),
           "target_faces": max(mesh.n_faces // 100, 300), "viewport": [1280, 720], "rows": []}
    print(json.dumps({k: v for k, v in out.items() if k != "rows"}), flush=True)
    for tolerance in (1.0, 4.0):
        for span in SPANS:
            row = at_rest(mesh, span, tolerance)
            out["rows"].append(row)
            print(json.dumps(row), flush=True)
    out["dolly"] = {str(t): dolly(mesh, t) for t in (1.0, 4.0)}
    print("dolly", json.dumps(out["dolly"]), flush=True)
    terrain, label = load_mesh("default", args.terrain_size)
    out["terrain"] = {"mesh": label, **terrain_flyover(terrain)}
    print("terrain", json.dumps(out["terrain"]), flush=True)
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / "parts.json").write_text(json.dumps(out, indent=2) + "\n")
    _plot(out)
    print(f"wrote {RESULTS / 'parts.json'} and parts.png")
    return 0


def _plot(out: dict) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(6.5, 3.8))
    for tolerance, style in ((1.0, "-"), (4.0, "--")):
        rows = [r for r in out["rows"] if r["tolerance_px"] == tolerance]
        spans = [r["span_px"] for r in rows]
        ax.plot(spans, [r["prune"]["faces"] for r in rows], "o" + style, color="C0",
                label=f"parts hidden, {tolerance:g} px")
        ax.plot(spans, [r["no_prune"]["faces"] for r in rows], "s" + style, color="C1",
                label=f"none hidden, {tolerance:g} px")
    ax.axhline(out["target_faces"], color="grey", lw=0.8, ls=":", label="target max(1 %, 300)")
    ax.set_xscale("log")
    ax.set_yscale("symlog", linthresh=10)
    ax.set_ylim(bottom=0)
    ax.invert_xaxis()
    ax.set_xlabel("width of the field on screen (px), nearer to farther")
    ax.set_ylabel("faces drawn")
    ax.set_title(f"debris field: {out['parts']:,} parts, {out['faces']:,} faces")
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(RESULTS / "parts.png", dpi=110)


if __name__ == "__main__":
    sys.exit(main())
