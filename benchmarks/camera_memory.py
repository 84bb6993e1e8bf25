"""Bytes per camera and update times on the 1M-triangle terrain, this tree against another.

    .venv/bin/python benchmarks/camera_memory.py [--baseline DIR] [--terrains default rough] [--sizes 708 1024]
        [--seconds 20] [--repeats 3]

Four cameras fly the flyover at 30 Hz (1280x720, 1 px) over each of
``--terrains`` (default: the smooth default terrain) built at each ``--sizes`` (708: 1M triangles, 1024: 2.1M), each
camera its own CameraState. Reported per tree and mesh: update time per
camera-frame (p50, p99; the first second, refining up from the base mesh,
left out), a camera's bytes at the end of the flight (median of the four)
and what they are made of: its node states (a byte per node of the mesh
before issue 16; a hash table of the blocks of nodes it holds since), the
face -> record map (a dense int32 per face of the mesh before issue 16; a
hash table over the active faces since), and the rest (records, active list).
With ``--baseline DIR`` (a checkout of another commit, e.g. ``git worktree
add DIR HEAD~3``) the same flights run on that tree's code, interleaved
with this tree's run by run, on the same ``.cvc`` files (built by this tree).
Writes ``benchmarks/results/camera_memory.json`` and a plot.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

RESULTS = Path(__file__).parent / "results"
HERE = Path(__file__).resolve().parents[1]

CHILD = r"""
import json, sys, time
import numpy as np
import caveclod
from caveclod.paths import flyover

mesh = caveclod.load(sys.argv[1])
seconds = float(sys.argv[2])
lo, hi = mesh.bounds()
cams = [mesh.new_camera() for _ in range(4)]
times = []
for frame in range(int(seconds * 30)):
    t = frame / 30.0
    for c, cam in enumerate(cams):
        p = flyover(lo, hi, c, t)
        view = caveclod.View(eye=p.eye, target=p.target, up=p.up, width=1280, height=720, tolerance_px=1.0)
        t0 = time.perf_counter()
        cam.update(view)
        if t >= 1.0:
            times.append(time.perf_counter() - t0)
def part(cam, name):
    a = getattr(cam, name, None)
    return 0 if a is None else int(a.nbytes)
rows = [{"bytes": cam.nbytes, "state_bytes": part(cam, "state"),
         "face_map_bytes": part(cam, "face_map") + part(cam, "face_rec"), "faces": cam.n_faces} for cam in cams]
print(json.dumps({"code": caveclod.__file__, "p50_ms": 1e3 * float(np.percentile(times, 50)),
                  "p99_ms": 1e3 * float(np.percentile(times, 99)), "updates": len(times), "cameras": rows,
                  "nodes": mesh.n_nodes, "mesh_faces": mesh.n_faces}))
"""


def run_child(tree: Path, path: Path, seconds: float) -> dict:
    # cwd too: ``python -c`` puts the working directory first on sys.path.
    out = subprocess.run([sys.executable, "-c", CHILD, str(path), str(seconds)], check=True, capture_output=True,
                         text=True, cwd=str(tree), env={**os.environ, "PYTHONPATH": str(tree)})
    return json.loads(out.stdout.strip().splitlines()[-1])


def summarize(runs: list[dict]) -> dict:
    med = statistics.median
    cams = [c for r in runs for c in r["cameras"]]
    return {"p50_ms": round(med(r["p50_ms"] for r in runs), 4), "p99_ms": round(med(r["p99_ms"] for r in runs), 4),
            "camera_bytes": med(c["bytes"] for c in cams), "state_bytes": med(c["state_bytes"] for c in cams),
            "face_map_bytes": med(c["face_map_bytes"] for c in cams), "faces": med(c["faces"] for c in cams),
            "nodes": runs[0]["nodes"], "mesh_faces": runs[0]["mesh_faces"], "runs": runs}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--baseline", type=Path, help="another checkout to compare with, run by run")
    ap.add_argument("--sizes", type=int, nargs="+", default=[708, 1024])
    ap.add_argument("--terrains", nargs="+", default=["default"], choices=["default", "rough"])
    ap.add_argument("--seconds", type=float, default=20.0)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--out", type=Path, default=RESULTS / "camera_memory.json")
    ap.add_argument("--mesh-dir", type=Path,
                    help="keep the built meshes as DIR/TERRAIN_SIZE.cvc and reuse those present (e.g. "
                         "benchmarks/results, where the other benchmarks keep theirs; default: built afresh in a "
                         "temporary directory)")
    args = ap.parse_args(argv)
    sys.path.insert(0, str(HERE))
    import caveclod
    trees = {"this": HERE}
    if args.baseline:
        trees["baseline"] = args.baseline.resolve()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for terrain, size in [(t, n) for t in args.terrains for n in args.sizes]:
            path = (args.mesh_dir or Path(tmp)) / f"{terrain}_{size}.cvc"
            if args.mesh_dir is None or not path.exists():
                caveclod.build(terrain, size=size).save(path)
            runs = {name: [] for name in trees}
            for _ in range(args.repeats):
                for name, tree in trees.items():
                    runs[name].append(run_child(tree, path, args.seconds))
            for name in trees:
                row = {"tree": name, "terrain": terrain, "size": size, **summarize(runs[name])}
                rows.append(row)
                print(f"{name} {terrain} --size {size} ({row['mesh_faces']:,} faces): update p50 "
                      f"{row['p50_ms']:.3f} ms, p99 {row['p99_ms']:.3f} ms; a camera "
                      f"{row['camera_bytes'] / 1e6:.2f} MB (state "
                      f"{row['state_bytes'] / 1e6:.2f}, face map {row['face_map_bytes'] / 1e6:.2f}) for "
                      f"{row['faces']:,.0f} faces", flush=True)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps({"command": "python benchmarks/camera_memory.py " + " ".join(argv or sys.argv[1:]),
                                    "results": rows}, indent=1))
    _plot(rows, args.out.with_suffix(".png"))
    return 0


def _plot(rows, path: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, (a, b) = plt.subplots(1, 2, figsize=(12, 4.2))
    labels = [f"{r['tree']}\n{r['terrain']}\n{r['mesh_faces'] / 1e6:.1f}M" for r in rows]
    xs = range(len(rows))
    a.bar(xs, [r["state_bytes"] / 1e6 for r in rows], label="node states")
    a.bar(xs, [r["face_map_bytes"] / 1e6 for r in rows], bottom=[r["state_bytes"] / 1e6 for r in rows],
          label="face -> record map")
    a.bar(xs, [(r["camera_bytes"] - r["state_bytes"] - r["face_map_bytes"]) / 1e6 for r in rows],
          bottom=[(r["state_bytes"] + r["face_map_bytes"]) / 1e6 for r in rows], label="records, list, rest")
    a.set_xticks(list(xs), labels, fontsize=7)
    a.set_ylabel("bytes per camera (MB)")
    a.legend(fontsize=8)
    b.bar([x - 0.2 for x in xs], [r["p50_ms"] for r in rows], 0.4, label="p50")
    b.bar([x + 0.2 for x in xs], [r["p99_ms"] for r in rows], 0.4, label="p99")
    b.set_xticks(list(xs), labels, fontsize=7)
    b.set_ylabel("update time per camera-frame (ms)")
    b.legend(fontsize=8)
    fig.suptitle("4-camera flyover at 1 px (medians of runs)")
    fig.tight_layout()
    fig.savefig(path, dpi=100)


if __name__ == "__main__":
    sys.exit(main())
