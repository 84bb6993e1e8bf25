"""Forced faces: how much of what a converged camera draws its own view does not ask for.

    .venv/bin/python benchmarks/forced_splits.py [--size 708] [--seconds 20]

On the smooth default and the rough terrain (1M triangles at --size 708),
four cameras fly the flyover at 1280x720 and converge at 1, 2 and 4 px;
every second of flight, each camera's split nodes are tested against its
view by their own criterion (:func:`caveclod.refine.measure.needs_detail`):
a split node that fails it is there only because a split the view does need
depends on it (Hoppe's dependencies), or because undoing it is not legal
yet. Each such split adds two faces: ``forced_share`` = 2 x forced splits /
active faces, the faces a truly selective refinement (Kim & Lee 2001) would
not draw (issue 18). Medians over cameras and seconds.

Writes benchmarks/results/forced_splits.json and forced_splits.png.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))
from refine import RESULTS, load_mesh  # noqa: E402


def measure(mesh, tolerance: float, seconds: float) -> dict:
    import caveclod
    from caveclod.paths import flyover
    from caveclod.refine.measure import forced_splits
    lo, hi = mesh.bounds()
    cams = [mesh.new_camera() for _ in range(4)]
    rows = []
    for second in range(1, int(seconds) + 1):
        for c, cam in enumerate(cams):
            p = flyover(lo, hi, c, float(second))
            view = caveclod.View(eye=p.eye, target=p.target, up=p.up, width=1280, height=720, tolerance_px=tolerance)
            cam.update(view)                       # no budget: one update converges
            rows.append(forced_splits(cam, view))
    return {"tolerance_px": tolerance, "samples": len(rows),
            "faces": statistics.median(r["faces"] for r in rows),
            "split_nodes": statistics.median(r["split_nodes"] for r in rows),
            "forced_nodes": statistics.median(r["forced_nodes"] for r in rows),
            "forced_share": round(statistics.median(r["forced_share"] for r in rows), 4),
            "forced_share_max": round(max(r["forced_share"] for r in rows), 4)}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--terrains", nargs="+", default=["default", "rough"])
    ap.add_argument("--size", type=int, default=708)
    ap.add_argument("--seconds", type=float, default=20.0)
    args = ap.parse_args()
    out = {"size": args.size, "seconds": args.seconds, "viewport": [1280, 720], "cameras": 4, "terrains": {}}
    for name in args.terrains:
        mesh, _ = load_mesh(name, args.size)
        out["terrains"][name] = [measure(mesh, t, args.seconds) for t in (1.0, 2.0, 4.0)]
        for row in out["terrains"][name]:
            print(name, json.dumps(row), flush=True)
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / "forced_splits.json").write_text(json.dumps(out, indent=2) + "\n")
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(6, 3.5))
    for name, rows in out["terrains"].items():
        ax.plot([r["tolerance_px"] for r in rows], [100 * r["forced_share"] for r in rows], "o-", label=name)
    ax.set_xlabel("tolerance (px)")
    ax.set_ylabel("faces from forced splits (%)")
    ax.set_title("converged cameras, 1M-triangle terrains, flyover")
    ax.legend()
    fig.tight_layout()
    fig.savefig(RESULTS / "forced_splits.png", dpi=110)
    print(f"wrote {RESULTS / 'forced_splits.json'} and forced_splits.png")
    return 0


if __name__ == "__main__":
    sys.exit(main())
