"""Build throughput and peak memory on the built-in terrains.

    python benchmarks/build.py [--terrains default rough] [--sizes 708 1024] [--repeats 3]

Each build runs in a fresh process (so peak memory is that build's own):
the process imports caveclod, warms the compiled kernels on a tiny terrain,
notes its resident memory, then generates and builds the terrain (the
smooth ``default`` and the ``rough`` one with no-data holes). Reported:
input triangles per second (generation included, medians over repeats),
peak memory added by the build per input triangle, and static bytes against
the paper's Equation 1. Writes ``benchmarks/results/build.json`` and a plot.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
from pathlib import Path

RESULTS = Path(__file__).parent / "results"

CHILD = r"""
import json, sys, time
import caveclod
from caveclod.builder.hierarchy import build_static_mesh
from caveclod.builder.builtin import BUILTINS, default_terrain

def rss_kb(field):
    for line in open("/proc/self/status"):
        if line.startswith(field):
            return int(line.split()[1])

build_static_mesh(default_terrain(16))          # compile / load cached kernels
base = rss_kb("VmRSS:")
size, terrain = int(sys.argv[1]), sys.argv[2]
t0 = time.perf_counter()
source = BUILTINS[terrain](size)
mesh = build_static_mesh(source)
seconds = time.perf_counter() - t0
s = mesh.summary()
print(json.dumps({"terrain": terrain, "size": size, "triangles": s["faces"], "seconds": seconds,
                  "peak_added_bytes": (rss_kb("VmHWM:") - base) * 1024,
                  "static_bytes": s["static_bytes"], "equation1_static_bytes": s["equation1_static_bytes"],
                  "base_faces": s["base_faces"], "nodes": s["nodes"], "passes": s["passes"]}))
"""


def run_one(terrain: str, size: int) -> dict:
    out = subprocess.run([sys.executable, "-c", CHILD, str(size), terrain], check=True, capture_output=True, text=True,
                         env={**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1])})
    return json.loads(out.stdout.strip().splitlines()[-1])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[708, 1024],
                    help="terrain cells per side (708 = 1.0M triangles, 1024 = 2.1M)")
    ap.add_argument("--terrains", nargs="+", default=["default", "rough"], choices=["default", "rough"])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--out", type=Path, default=RESULTS / "build.json")
    args = ap.parse_args(argv)
    rows = []
    for terrain, size in [(t, n) for t in args.terrains for n in args.sizes]:
        runs = [run_one(terrain, size) for _ in range(args.repeats)]
        tri = runs[0]["triangles"]
        row = {
            "terrain": terrain,
            "size": size,
            "triangles": tri,
            "seconds_median": statistics.median(r["seconds"] for r in runs),
            "triangles_per_second_median": statistics.median(tri / r["seconds"] for r in runs),
            "peak_bytes_per_triangle_median": statistics.median(r["peak_added_bytes"] / tri for r in runs),
            "static_bytes": runs[0]["static_bytes"],
            "equation1_static_bytes": runs[0]["equation1_static_bytes"],
            "static_over_equation1": runs[0]["static_bytes"] / runs[0]["equation1_static_bytes"],
            "base_faces": runs[0]["base_faces"],
            "runs": runs,
        }
        rows.append(row)
        print(f"{terrain} {size}: {tri:,} triangles, {row['triangles_per_second_median']:,.0f} tri/s, "
              f"peak {row['peak_bytes_per_triangle_median']:.0f} B/tri, static {row['static_bytes']:,} B "
              f"({row['static_over_equation1']:.2f} of Equation 1), base {row['base_faces']} faces", flush=True)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps({"command": "python benchmarks/build.py " + " ".join(argv or sys.argv[1:]),
                                    "machine_cores": os.cpu_count(), "results": rows}, indent=1))
    _plot(rows, args.out.with_suffix(".png"))
    return 0


def _plot(rows, path: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, (a, b) = plt.subplots(1, 2, figsize=(9, 3.5))
    labels = [f"{r['terrain']}\n{r['triangles'] / 1e6:.1f}M" for r in rows]
    a.bar(labels, [r["triangles_per_second_median"] / 1e3 for r in rows])
    a.axhline(200, color="k", ls="--", lw=1, label="target 200k/s")
    a.set_ylabel("input triangles per second (thousands)")
    a.legend()
    b.bar(labels, [r["peak_bytes_per_triangle_median"] for r in rows])
    b.axhline(1024, color="k", ls="--", lw=1, label="target 1 KB")
    b.set_ylabel("peak bytes per input triangle")
    b.legend()
    fig.suptitle("caveclod build, built-in terrains (medians)")
    fig.tight_layout()
    fig.savefig(path, dpi=100)


if __name__ == "__main__":
    sys.exit(main())
