"""The paper's experiments: multi-camera flyovers, per-camera vs shared state.

    python benchmarks/refine.py [--terrains default rough | --mesh X.cvc] [--size 708] [--seconds 20]

On the smooth default terrain and the rough one (1M triangles at --size
708), for 1, 2, 3 and 4 cameras flying over different parts of the mesh at
30 Hz (1280x720, 60 degree field of view, 1 px tolerance):

* **per-camera**: each camera has its own CameraState (CAVECLOD);
* **baseline**: one CameraState re-refined for camera A, then B, ... each
  frame (the paper's application without CAVECLOD).

Reported: split+collapse operations per camera-second in both modes and
their ratio (paper Figs. 10-11), update time per camera-frame (p50, p99),
active faces per camera (Fig. 13), bytes per added camera against the static
mesh and against Equation 1's per-camera term for the same active counts
(Table 1, Fig. 14), the speed-up of 2 threads over 1 updating 2 cameras, the
cost of a converged update per active node (with expiries and without), and
the updates a jump takes to converge in either direction. The first second
(refining up from the base mesh) is left out of rates and times. Writes
``benchmarks/results/refine.json`` and ``refine_<terrain>_*.png``.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

import caveclod
from caveclod.builder.version import made_by_this_code
from caveclod.paths import flyover

RESULTS = Path(__file__).parent / "results"
FPS = 30


def load_mesh(name: str, size: int):
    """A built-in, built once into benchmarks/results/ (or a .cvc path)."""
    if name.endswith(".cvc"):
        return caveclod.load(name), name
    path = RESULTS / f"{name}_{size}.cvc"
    if not made_by_this_code(path):           # absent, or built by other code: build it again
        path.parent.mkdir(parents=True, exist_ok=True)
        caveclod.build(name, size=size).save(path)
    return caveclod.load(path), f"{name} --size {size}"


def views_for(lo, hi, cameras, frames, tolerance):
    return [[caveclod.View.from_pose(flyover(lo, hi, c, f / FPS), tolerance_px=tolerance) for c in range(cameras)]
            for f in range(frames)]


def per_camera(mesh, views, **options):
    """Each camera its own state (``options``: ``mesh.new_camera``'s). Returns ops, seconds, faces: (frames, cams)."""
    cams = [mesh.new_camera(**options) for _ in views[0]]
    ops, secs, faces = (np.zeros((len(views), len(cams))) for _ in range(3))
    for f, frame in enumerate(views):
        for c, (cam, view) in enumerate(zip(cams, frame)):
            d = cam.update(view)
            ops[f, c], secs[f, c], faces[f, c] = d.operations, d.seconds, cam.n_faces
    return ops, secs, faces, cams


def flight(mesh, views, **options) -> dict:
    """One flyover of :func:`per_camera` (``options``: ``mesh.new_camera``'s): update p50 and p99 per
    camera-frame in ms, faces a camera (mean) and operations, the first second left out."""
    ops, secs, faces, _ = per_camera(mesh, views, **options)
    s = secs[FPS:].ravel() * 1e3                      # the first second refines up from the base mesh
    return {"update_ms_p50": float(np.percentile(s, 50)), "update_ms_p99": float(np.percentile(s, 99)),
            "faces_mean": float(faces[FPS:].mean()), "operations": int(ops[FPS:].sum())}


def compare_flights(variants: dict, views, repeats: int, label: str) -> dict:
    """Fly each of ``variants`` ({name: (mesh, new_camera options)}) one after the other in each of
    ``repeats`` rounds, so that drift of the machine hits all alike; print each variant's medians.
    Returns ``{"runs": {name: [flight, ...]}, "median": {name: {figure: median}}}``."""
    runs = {k: [] for k in variants}
    for _ in range(repeats):
        for k, (mesh, options) in variants.items():
            runs[k].append(flight(mesh, views, **options))
    med = {k: {q: statistics.median(r[q] for r in rs) for q in rs[0]} for k, rs in runs.items()}
    width = max(len(k) for k in variants)
    for k in variants:
        m = med[k]
        print(f"{label} {k:{width}s}: update p50 {m['update_ms_p50']:.3f} ms p99 {m['update_ms_p99']:.3f} ms; "
              f"{m['faces_mean']:,.0f} faces a camera; {m['operations']:,.0f} operations", flush=True)
    return {"runs": runs, "median": med}


def shared_state(mesh, views):
    """The paper's baseline: one state refined for each camera in turn."""
    cam = mesh.new_camera()
    ops, secs = np.zeros((len(views), len(views[0]))), np.zeros((len(views), len(views[0])))
    for f, frame in enumerate(views):
        for c, view in enumerate(frame):
            d = cam.update(view)
            ops[f, c], secs[f, c] = d.operations, d.seconds
    return ops, secs


def threaded(mesh, views, threads):
    """Wall seconds to run the cameras' flyovers on ``threads`` threads.

    Returns (wall seconds, summed update seconds per camera). Each camera is
    first refined for its first view, so both runs time steady refinement.
    """
    cams = [mesh.new_camera() for _ in views[0]]
    for cam, view in zip(cams, views[0]):
        cam.update(view)
    busy = [0.0] * len(cams)

    def run(c):
        for frame in views[1:]:
            busy[c] += cams[c].update(frame[c]).seconds

    t0 = time.perf_counter()
    if threads == 1:
        for c in range(len(cams)):
            run(c)
    else:
        with ThreadPoolExecutor(threads) as pool:
            list(pool.map(run, range(len(cams))))
    return time.perf_counter() - t0, busy


def speedup(mesh, views, repeats):
    """Median speed-up of 2 threads over 1 thread on two cameras' flyovers.

    Also the best possible speed-up given how unequal the cameras' work is
    (total work over the larger camera's share).
    """
    one, two = [], []
    for _ in range(repeats):        # interleaved, so drift of the machine hits both alike
        one.append(threaded(mesh, views, 1))
        two.append(threaded(mesh, views, 2))
    bound = statistics.median(sum(b) / max(b) for _, b in one)
    return {"one_thread_seconds": [w for w, _ in one], "two_threads_seconds": [w for w, _ in two],
            "speedup_median": statistics.median(a / b for (a, _), (b, _) in zip(one, two)),
            "speedup_bound_from_imbalance": bound}


def equation1_per_camera(mesh, cam) -> int:
    """4n + 4p + 16 + 12 n_a + 36 p_a for one camera (paper Equation 1)."""
    return 4 * mesh.n_nodes + 4 * mesh.n_faces + 16 + 12 * len(cam.active_nodes()) + 36 * cam.n_faces


def converged_cost(mesh, lo, hi, tolerance, repeats=50):
    """Microseconds of an update that changes nothing, per active node,
    with expiries (a converged camera's real cost) and without (every
    active node tested): median over the four flyover cameras."""
    out = {"with_expiries_us_per_active_node": [], "without_expiries_us_per_active_node": [],
           "with_expiries_us": [], "without_expiries_us": [], "active_nodes": []}
    for c in range(4):
        view = caveclod.View.from_pose(flyover(lo, hi, c, 0.0), tolerance_px=tolerance)
        for key, options in (("with", {}), ("without", {"expiries": False})):
            cam = mesh.new_camera(**options)
            for _ in range(5):
                if cam.update(view).operations == 0:
                    break
            times = []
            for _ in range(repeats):
                t0 = time.perf_counter()
                cam.update(view)
                times.append(time.perf_counter() - t0)
            us = 1e6 * statistics.median(times)
            nodes = len(cam.active_nodes())
            out[f"{key}_expiries_us"].append(us)
            out[f"{key}_expiries_us_per_active_node"].append(us / nodes)
        out["active_nodes"].append(nodes)
    return {k: statistics.median(v) for k, v in out.items()}


def jumps(mesh, lo, hi, tolerance):
    """Updates until an update makes no operation, after jumps both ways."""
    ext = float(np.linalg.norm(hi - lo))
    centre = (lo + hi) / 2
    far = caveclod.View(eye=tuple(centre + ext * np.array([20.0, 3.0, 6.0])), target=tuple(centre),
                        tolerance_px=tolerance)
    out = {}
    for c in range(4):
        near = caveclod.View.from_pose(flyover(lo, hi, c, 0.0), tolerance_px=tolerance)
        cam = mesh.new_camera()
        for label, view in (("refine", near), ("coarsen", far), ("refine_again", near)):
            k = 0
            while cam.update(view).operations and k < 20:
                k += 1
            out.setdefault(label, []).append(k)
    return {k: max(v) for k, v in out.items()}


def run_terrain(name, args):
    mesh, label = load_mesh(name, args.size)
    lo, hi = mesh.bounds()
    frames = int(args.seconds * FPS)
    warm = FPS                                           # leave out the first second
    mesh.new_camera().update(caveclod.View.from_pose(flyover(lo, hi, 0, 0.0)))  # compile/load kernels
    report = {"mesh": label, "triangles": mesh.n_faces, "static_bytes": mesh.nbytes,
              "equation1_static_bytes": mesh.equation1_bytes, "frames": frames, "fps": FPS,
              "tolerance_px": args.tolerance, "cameras": {}}
    series = {}
    for n_cams in (1, 2, 3, 4):
        views = views_for(lo, hi, n_cams, frames, args.tolerance)
        # Timings drift on shared machines: repeat the per-camera flyover and
        # take medians of its percentiles (its operations are deterministic).
        runs = [per_camera(mesh, views) for _ in range(args.repeats)]
        ops, secs, faces, cams = runs[0]
        p50s = [float(np.percentile(r[1][warm:] * 1000, 50)) for r in runs]
        p99s = [float(np.percentile(r[1][warm:] * 1000, 99)) for r in runs]
        bops, bsecs = shared_state(mesh, views)
        sim = (frames - warm) / FPS
        pc_rate = ops[warm:].sum() / (n_cams * sim)
        bl_rate = bops[warm:].sum() / (n_cams * sim)
        t_ms = secs[warm:].ravel() * 1000
        cam_bytes = [c.nbytes for c in cams]
        eq1 = [equation1_per_camera(mesh, c) for c in cams]
        row = {
            "ops_per_camera_second": pc_rate,
            "baseline_ops_per_camera_second": bl_rate,
            "baseline_over_per_camera": bl_rate / max(pc_rate, 1e-9),
            "update_ms_p50": statistics.median(p50s),
            "update_ms_p99": statistics.median(p99s),
            "update_ms_p99_each_repeat": p99s,
            "baseline_update_ms_p50": float(np.percentile(bsecs[warm:].ravel() * 1000, 50)),
            "active_faces_mean": float(faces[warm:].mean()),
            "bytes_per_camera": cam_bytes,
            "camera_over_static": max(cam_bytes) / mesh.nbytes,
            "equation1_bytes_per_camera": eq1,
            "camera_over_equation1": max(b / q for b, q in zip(cam_bytes, eq1)),
            "equation1_camera_over_static": max(eq1) / mesh.equation1_bytes,
        }
        report["cameras"][n_cams] = row
        series[n_cams] = (ops, bops, faces, t_ms)
        print(f"{name} {n_cams} camera(s): per-camera {pc_rate:,.0f} ops/cam-s, baseline {bl_rate:,.0f} "
              f"({row['baseline_over_per_camera']:.1f}x); update p50 {row['update_ms_p50']:.2f} ms "
              f"p99 {row['update_ms_p99']:.2f} ms; {row['active_faces_mean']:,.0f} faces/camera; "
              f"camera = {100 * row['camera_over_static']:.1f}% of static, "
              f"{row['camera_over_equation1']:.2f} of Eq. 1's per-camera term", flush=True)

    # Two threads, two cameras: the paper's cameras A and B (which see
    # unequal amounts of terrain), and two cameras of equal load (each its
    # own state, both flying camera A's path) that isolate parallel scaling.
    paper = views_for(lo, hi, 2, frames, args.tolerance)
    equal = [[frame[0], frame[0]] for frame in paper]
    report["threads"] = {"cores": os.cpu_count(),
                         "cameras_a_b": speedup(mesh, paper, args.repeats),
                         "equal_load": speedup(mesh, equal, args.repeats)}
    for what, row in (("cameras A, B", report["threads"]["cameras_a_b"]),
                      ("equal load", report["threads"]["equal_load"])):
        print(f"{name} 2 threads vs 1, {what}: speed-up {row['speedup_median']:.2f}x "
              f"(imbalance allows {row['speedup_bound_from_imbalance']:.2f}x); "
              f"1 thread {statistics.median(row['one_thread_seconds']):.2f} s", flush=True)
    report["converged_update"] = converged_cost(mesh, lo, hi, args.tolerance)
    report["updates_to_converge"] = jumps(mesh, lo, hi, args.tolerance)
    cu = report["converged_update"]
    print(f"{name} converged update: {cu['with_expiries_us']:.0f} us with expiries "
          f"({1000 * cu['with_expiries_us_per_active_node']:.1f} ns per active node), "
          f"{cu['without_expiries_us']:.0f} us without ({1000 * cu['without_expiries_us_per_active_node']:.1f} ns); "
          f"updates to converge after a jump: {report['updates_to_converge']}", flush=True)
    _plot(series, report, args.out.parent, name)
    return report


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--terrains", nargs="+", default=["default", "rough"],
                    help="built-ins (or .cvc paths) to fly over")
    ap.add_argument("--size", type=int, default=708, help="cells per side of the built-ins (708 = 1.0M triangles)")
    ap.add_argument("--seconds", type=float, default=20.0, help="simulated flyover length")
    ap.add_argument("--tolerance", type=float, default=1.0, help="screen-space tolerance in pixels")
    ap.add_argument("--repeats", type=int, default=3, help="repeats of each timing (medians are reported)")
    ap.add_argument("--out", type=Path, default=RESULTS / "refine.json")
    args = ap.parse_args(argv)
    report = {"terrains": {name: run_terrain(name, args) for name in args.terrains}}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(report, indent=1))
    return 0


def _plot(series, report, folder: Path, name: str) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    ops, bops, faces, _ = series[4]
    t = np.arange(len(ops)) / FPS
    secs = np.arange(int(t[-1]) + 1)
    per_sec = lambda a: np.array([a[(t >= s) & (t < s + 1)].sum(axis=0) for s in secs])  # noqa: E731
    fig, (a, b) = plt.subplots(1, 2, figsize=(11, 4), sharey=True)
    for c, label in enumerate("ABCD"):
        a.plot(secs, per_sec(bops)[:, c], label=f"camera {label}")
        b.plot(secs, per_sec(ops)[:, c], label=f"camera {label}")
    a.set_title("shared state (paper Fig. 10)")
    b.set_title("per-camera states, CAVECLOD (Fig. 11)")
    a.set_xlabel("flyover time (s)")
    b.set_xlabel("flyover time (s)")
    a.set_ylabel("split + collapse operations per second")
    a.set_yscale("symlog")
    a.legend()
    fig.tight_layout()
    fig.savefig(folder / f"refine_{name}_ops.png", dpi=100)

    fig, (a, b) = plt.subplots(1, 2, figsize=(11, 4))
    for c, label in enumerate("ABCD"):
        a.plot(t, faces[:, c], label=f"camera {label}")
    a.set_title("active faces per camera, 4-camera flyover (Fig. 13)")
    a.set_xlabel("flyover time (s)")
    a.legend()
    n = sorted(report["cameras"], key=int)
    static = report["static_bytes"] / 2 ** 20
    total = [static + sum(report["cameras"][k]["bytes_per_camera"]) / 2 ** 20 for k in n]
    a_cam = [static] + total
    b.plot([0] + [int(k) for k in n], a_cam, "o-", label="static + cameras")
    b.axhline(static, color="k", ls="--", lw=1, label="static mesh")
    b.set_xticks([0] + [int(k) for k in n])
    b.set_title("memory vs cameras (Fig. 14)")
    b.set_xlabel("cameras")
    b.set_ylabel("MiB")
    b.set_ylim(0, None)
    b.legend()
    fig.tight_layout()
    fig.savefig(folder / f"refine_{name}_faces_memory.png", dpi=100)

    fig, ax = plt.subplots(figsize=(5.5, 4))
    for k in n:
        x = np.sort(series[int(k)][3])
        ax.plot(x, np.linspace(0, 1, len(x)), label=f"{k} camera(s)")
    ax.axvline(2.0, color="k", ls="--", lw=1, label="2 ms")
    ax.set_xlabel("update time per camera-frame (ms)")
    ax.set_ylabel("fraction of frames")
    ax.set_xscale("log")
    ax.legend()
    fig.tight_layout()
    fig.savefig(folder / f"refine_{name}_update_cdf.png", dpi=100)


if __name__ == "__main__":
    sys.exit(main())
