"""Build throughput and peak memory on the built-in terrains, in one tile and in tiles.

    python benchmarks/build.py [--terrains default rough] [--sizes 708 1024] [--repeats 3] [--modes single tiled]
                               [--baseline DIR]

Each build runs in a fresh process (so peak memory is that build's own):
the process imports caveclod, warms the compiled kernels on a tiny terrain,
notes its resident memory, then generates and builds the terrain (the
smooth ``default`` and the ``rough`` one with no-data holes), ``single``
(``tiles=1``: one region, in halves on two threads) or ``tiled`` (the
automatic grid: tiles simplified in parallel with fixed borders, merged
2 x 2; :mod:`caveclod.builder.tiles`). Reported: input triangles per
second (generation included, and the build alone; medians over repeats), peak memory added by
the build per input triangle, static bytes against the paper's Equation 1,
passes and the hierarchy's height (longest leaf-to-root path), and, once per
input, the same process's time for meshoptimizer's simplifier halving the
mesh down to as many faces as the build's base mesh (a chain of
``simplify`` calls, positions only: no attributes, no hierarchy, no
measured bounds; a yardstick for speed, not an equal). For the first
repeat, the refinement it gives: four cameras of the flyover at 1280x720
and 1 px, converged, their median faces and the share of faces from splits
their own view does not ask for (:func:`caveclod.refine.measure.forced_splits`).
``--baseline DIR`` builds the same inputs with the checkout in DIR too
(``git worktree add DIR REV``), interleaved with this one's run by run, so
that the two are compared within one run. Writes
``benchmarks/results/build.json`` and a plot.
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
import json, statistics, sys, time
import numpy as np
import caveclod
from caveclod.builder.hierarchy import build_static_mesh
from caveclod.builder.builtin import BUILTINS, default_terrain

def rss_kb(field):
    for line in open("/proc/self/status"):
        if line.startswith(field):
            return int(line.split()[1])

def height(mesh):
    e, links = mesh.n_positions, np.asarray(mesh.node_links)
    h = np.zeros(e + len(links), np.int32)
    while True:                      # children before parents: at most height rounds
        new = 1 + np.maximum(h[links[:, 0]], h[links[:, 1]])
        if np.array_equal(new, h[e:]):
            return int(h.max())
        h[e:] = new

def refinement(mesh):
    from caveclod.paths import flyover
    from caveclod.refine.measure import forced_splits
    lo, hi = mesh.bounds()
    rows = []
    for c in range(4):
        p = flyover(lo, hi, c, 10.0)
        view = caveclod.View(eye=p.eye, target=p.target, up=p.up, width=1280, height=720, tolerance_px=1.0)
        cam = mesh.new_camera()
        cam.update(view)
        rows.append(forced_splits(cam, view))
    return {"faces_1px": statistics.median(r["faces"] for r in rows),
            "forced_share_1px": round(statistics.median(r["forced_share"] for r in rows), 4)}

def meshoptimizer_chain(source, target_faces):
    import meshoptimizer
    pos = np.ascontiguousarray(source.positions, np.float32)
    idx = np.ascontiguousarray(source.face_positions, np.uint32).ravel()
    t0 = time.perf_counter()
    while len(idx) // 3 > target_faces:
        out = np.empty_like(idx)
        n = meshoptimizer.simplify(out, idx, pos, target_index_count=max(3 * target_faces, len(idx) // 6 * 3),
                                   target_error=1.0)
        if n >= len(idx):
            break
        idx = out[:n].copy()
    return time.perf_counter() - t0, len(idx) // 3

build_static_mesh(default_terrain(16))          # compile / load cached kernels
base = rss_kb("VmRSS:")
size, terrain, tiles, extras = int(sys.argv[1]), sys.argv[2], sys.argv[3], sys.argv[4] == "1"
tiles = None if tiles == "auto" else int(tiles)
t0 = time.perf_counter()
made = [BUILTINS[terrain](size)]
t1 = time.perf_counter()
mesh = build_static_mesh(made.pop, tiles=tiles)      # the build holds the only reference, as in caveclod.build
seconds = time.perf_counter() - t0
build_seconds = time.perf_counter() - t1
peak = (rss_kb("VmHWM:") - base) * 1024
s = mesh.summary()
row = {"terrain": terrain, "size": size, "triangles": s["faces"], "seconds": seconds, "build_seconds": build_seconds,
       "peak_added_bytes": peak,
       "static_bytes": s["static_bytes"], "equation1_static_bytes": s["equation1_static_bytes"],
       "base_faces": s["base_faces"], "nodes": s["nodes"], "passes": s["passes"], "tiles": mesh.info["tiles"],
       "height": height(mesh), "module": caveclod.__file__}
if extras:
    row.update(refinement(mesh))
    row["meshoptimizer_seconds"], row["meshoptimizer_faces"] = meshoptimizer_chain(BUILTINS[terrain](size),
                                                                                   s["base_faces"])
print(json.dumps(row))
"""

MODES = {"single": "1", "tiled": "auto"}


HERE = Path(__file__).resolve().parents[1]


def run_one(terrain: str, size: int, mode: str, extras: bool, checkout: Path = HERE) -> dict:
    """One build in a fresh process of ``checkout``'s caveclod (the child runs in
    that directory, which Python searches before an installed caveclod)."""
    out = subprocess.run([sys.executable, "-c", CHILD, str(size), terrain, MODES[mode], "1" if extras else "0"],
                         check=True, capture_output=True, text=True, cwd=checkout,
                         env={**os.environ, "PYTHONPATH": str(checkout)})
    row = json.loads(out.stdout.strip().splitlines()[-1])
    if not Path(row["module"]).resolve().is_relative_to(Path(checkout).resolve()):
        raise SystemExit(f"the build meant for {checkout} imported {row['module']}: check that DIR is a checkout")
    return row


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[708, 1024],
                    help="terrain cells per side (708 = 1.0M triangles, 1024 = 2.1M)")
    ap.add_argument("--terrains", nargs="+", default=["default", "rough"], choices=["default", "rough"])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--modes", nargs="+", default=list(MODES), choices=list(MODES))
    ap.add_argument("--out", type=Path, default=RESULTS / "build.json")
    ap.add_argument("--baseline", type=Path, help="a checkout whose build to run beside this one's, interleaved")
    args = ap.parse_args(argv)
    checkouts = {"this": HERE}
    if args.baseline is not None:
        checkouts["baseline"] = args.baseline.resolve()
    rows = []
    for terrain, size in [(t, n) for t in args.terrains for n in args.sizes]:
        # Modes and checkouts interleaved repeat by repeat, so that a noisy
        # minute hits them alike.
        runs = {(mode, name): [] for mode in args.modes for name in checkouts}
        for rep in range(args.repeats):
            for mode in args.modes:
                for name in (list(checkouts) if rep % 2 == 0 else list(checkouts)[::-1]):
                    runs[mode, name].append(run_one(terrain, size, mode, extras=rep == 0, checkout=checkouts[name]))
        for (mode, name), rs in runs.items():
            tri = rs[0]["triangles"]
            row = {
                "checkout": name, "terrain": terrain, "size": size, "mode": mode, "tiles": rs[0]["tiles"],
                "triangles": tri,
                "seconds_median": statistics.median(r["seconds"] for r in rs),
                "triangles_per_second_median": statistics.median(tri / r["seconds"] for r in rs),
                "build_triangles_per_second_median": statistics.median(tri / r["build_seconds"] for r in rs),
                "peak_bytes_per_triangle_median": statistics.median(r["peak_added_bytes"] / tri for r in rs),
                "static_bytes": rs[0]["static_bytes"],
                "equation1_static_bytes": rs[0]["equation1_static_bytes"],
                "static_over_equation1": rs[0]["static_bytes"] / rs[0]["equation1_static_bytes"],
                "base_faces": rs[0]["base_faces"], "passes": rs[0]["passes"], "height": rs[0]["height"],
                "faces_1px": rs[0]["faces_1px"], "forced_share_1px": rs[0]["forced_share_1px"],
                "meshoptimizer_seconds": rs[0]["meshoptimizer_seconds"],
                "meshoptimizer_ratio": (statistics.median(r["build_seconds"] for r in rs)
                                        / rs[0]["meshoptimizer_seconds"]),
                "runs": rs,
            }
            rows.append(row)
            print(f"{'' if name == 'this' else 'baseline: '}{terrain} {size} {mode} (tiles {row['tiles']}): "
                  f"{tri:,} triangles, "
                  f"{row['triangles_per_second_median']:,.0f} tri/s ({row['build_triangles_per_second_median']:,.0f} "
                  f"without generating the input), peak {row['peak_bytes_per_triangle_median']:.0f} "
                  f"B/tri, static {row['static_over_equation1']:.2f} of Equation 1, base {row['base_faces']} faces, "
                  f"{row['passes']} passes, height {row['height']}, {row['faces_1px']:,.0f} faces at 1 px "
                  f"({100 * row['forced_share_1px']:.1f} % forced), {row['meshoptimizer_ratio']:.1f} x "
                  "meshoptimizer's chain", flush=True)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps({"command": "python benchmarks/build.py " + " ".join(argv or sys.argv[1:]),
                                    "machine_cores": os.cpu_count(),
                                    "checkouts": {k: str(v) for k, v in checkouts.items()}, "results": rows},
                                   indent=1))
    _plot(rows, args.out.with_suffix(".png"))
    return 0


def _plot(rows, path: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, (a, b) = plt.subplots(1, 2, figsize=(10, 3.8))
    inputs = sorted({(r["terrain"], r["size"], r["triangles"]) for r in rows}, key=lambda k: (k[0], k[1]))
    series = sorted({(r["mode"], r.get("checkout", "this")) for r in rows}, key=lambda m: (m[0], m[1] != "this"))
    width = 0.8 / len(series)
    for j, (mode, name) in enumerate(series):
        sel = [next((r for r in rows if (r["terrain"], r["size"]) == k[:2] and r["mode"] == mode
                     and r.get("checkout", "this") == name), None) for k in inputs]
        xs = [i + j * width for i in range(len(inputs))]
        label = mode if name == "this" else f"{mode}, baseline"
        a.bar(xs, [r["build_triangles_per_second_median"] / 1e3 if r else 0 for r in sel], width, label=label)
        b.bar(xs, [r["peak_bytes_per_triangle_median"] if r else 0 for r in sel], width, label=label)
    labels = [f"{t}\n{n / 1e6:.1f}M" for t, _, n in inputs]
    for ax in (a, b):
        ax.set_xticks([i + 0.4 - width / 2 for i in range(len(inputs))], labels)
    a.axhline(300, color="k", ls="--", lw=1, label="target 300k/s")
    a.set_ylabel("input triangles per second, build alone (k)")
    a.legend(fontsize=8)
    b.axhline(100, color="k", ls="--", lw=1, label="target 100 B (tiled)")
    b.set_ylabel("peak bytes per input triangle")
    b.legend(fontsize=8)
    fig.suptitle("caveclod build, built-in terrains, one tile and tiled (medians)")
    fig.tight_layout()
    fig.savefig(path, dpi=100)


if __name__ == "__main__":
    sys.exit(main())
