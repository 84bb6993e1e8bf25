"""What the ring test costs a camera: the same build with its ring bounds and without.

    python benchmarks/ring_test.py [--terrains default rough] [--size 708] [--seconds 20] [--repeats 3]

The ring test (docs/error-bounds.md, "Original -> LOD") splits a node when
a node beside its collapse needs detail by its own test. A file without the
optional ``node_ring`` array refines without it, so one build, with the
array and with it dropped, isolates the test's cost from everything else.
Four cameras fly over each 1M-triangle built-in (``refine.py``'s flyovers:
1280x720, 1 px, 30 Hz, the first second left out); the two variants run
one after the other in each repeat, so drift of the machine hits both.

Reported per terrain and variant: update p50 and p99 per camera-frame (the
median of the repeats' values), active faces a camera (mean), operations.
Writes ``benchmarks/results/ring_test.json`` and ``ring_test.png``.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from refine import FPS, RESULTS, compare_flights, load_mesh, views_for  # noqa: E402

CAMERAS = 4


def without_ring(mesh):
    """The same static mesh without its ring bounds (as a file from before them)."""
    from caveclod.staticmesh import StaticMesh
    return StaticMesh(arrays={k: v for k, v in mesh.arrays.items() if k != "node_ring"},
                      materials=mesh.materials)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--terrains", nargs="+", default=["default", "rough"])
    ap.add_argument("--size", type=int, default=708, help="cells per side of the built-ins (708 = 1.0M triangles)")
    ap.add_argument("--seconds", type=float, default=20.0, help="flyover length")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--out", type=Path, default=RESULTS / "ring_test.json")
    args = ap.parse_args(argv)
    report = {"cameras": CAMERAS, "seconds": args.seconds, "repeats": args.repeats, "terrains": {}}
    for name in args.terrains:
        mesh, label = load_mesh(name, args.size)
        if "node_ring" not in mesh.arrays:
            print(f"{label}: the file has no ring bounds (built before them): delete it to rebuild", file=sys.stderr)
            return 2
        lo, hi = mesh.bounds()
        views = views_for(lo, hi, CAMERAS, int(args.seconds * FPS), 1.0)
        variants = {"ring test": (mesh, {}), "without": (without_ring(mesh), {})}
        report["terrains"][name] = {"mesh": label, **compare_flights(variants, views, args.repeats, label)}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(report, indent=1))
    _plot(report, args.out.with_suffix(".png"))
    return 0


def _plot(report: dict, path: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    names = list(report["terrains"])
    fig, axes = plt.subplots(1, 3, figsize=(12, 3.6))
    for ax, (q, title) in zip(axes, (("update_ms_p50", "update p50, ms"), ("update_ms_p99", "update p99, ms"),
                                     ("faces_mean", "faces a camera"))):
        x = np.arange(len(names))
        for i, k in enumerate(("without", "ring test")):
            ax.bar(x + (i - 0.5) * 0.38, [report["terrains"][n]["median"][k][q] for n in names], 0.38, label=k)
        ax.set_xticks(x, names)
        ax.set_title(title)
    axes[0].legend()
    fig.suptitle("the ring test's cost: 4 cameras on the 1M-triangle flyovers at 1 px")
    fig.tight_layout()
    fig.savefig(path, dpi=110)


if __name__ == "__main__":
    raise SystemExit(main())
