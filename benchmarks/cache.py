"""Cache mode: vertices inserted and bytes per frame for FA, LRU and LRU+PQ (Lario et al. Tables 2 and 4).

    python benchmarks/cache.py [--meshes default,blob,blob-backface,rough] [--sizes 0.75,1,2,4] [--object-frames 1000]
                               [--terrain-frames 3000] [--terrain-size 512] [--blob-subdivisions 7]

The paper's three trajectories (``caveclod.paths``: ``circle``, ``rotate``,
``line``; its Figures 9 and 12; round the object, its "small rotations" are
``swing``, the eye swinging round the centre and looking at it, while
``rotate`` turns the view about a fixed eye as Figure 12b does over the
terrain) at 30 poses a second, one refinement update
per pose (what ``caveclod serve`` makes when poses come faster than its 50 ms
convergence pause), 1 px tolerance, 45 degree field of view:

* the default terrain (``--terrain-size 512``: 524,288 triangles), 3000
  frames at 1024x768, as Table 4 (Puget Sound) was measured;
* ``blob``: a closed scanned-style object, an icosphere displaced by three
  octaves of noise and scanner noise, smooth normals (``--blob-subdivisions
  7``: 327,680 triangles, 163,842 vertices), 1000 frames at 800x800, as
  Table 2 (the Dragon) was measured;
* ``blob-backface``: the same with back faces culled too (normal cones):
  the paper does not say whether FastMesh culled them; with the frustum
  alone, a closed object's far side stays refined and an orbit at constant
  distance hardly changes the level of detail;
* ``rough`` (also by default): the rough terrain, whose fractal detail is
  closer to a real elevation model such as Puget Sound.

Each run covers one lap of the circle, one trip out and back along the line,
and rotations (or swings) of +-15 degrees every 8 s (paths' own period). Cache sizes are
multiples (``--sizes``) of P, the most vertices any frame of the mesh's three
trajectories needs; 2 x P is the paper's choice (2^17 slots for a Dragon
that needed up to 2^16). Below 1 x P a frame can need more vertices than
slots: the camera is coarsened (``caveclod.refine.cachedcamera``), which the
runs report as the largest tolerance reached.

For every (mesh, trajectory, size, strategy): vertices inserted in all
(frame 1's base mesh and the refinement up from it included, as the paper
counts from an empty cache) and after the first frame (where the strategies
differ; the paper's totals are dominated by that part, ours by the first
fill, see ``comparison``), per frame (mean, max), the hit rate (of the
vertices that became active, the share still in a slot), and wire bytes per
frame as ``caveclod serve`` encodes them (``caveclod.wire.frame_parts``;
vertex writes: 32 bytes a vertex plus 4 a slot unless the slots run
consecutively), against resident mode's frames (``frame_bytes_over_resident``)
and against those plus its one-time vertex buffer download
(``bytes_over_resident_with_vertex_buffer``); per run, the churn
(``activated_per_frame_after_first``). Counts and bytes are deterministic. Times (median
microseconds a frame: refinement, active-vertex tracking, each strategy's
victim choice) are this shared machine's. Then the case for caches per
camera rather than per session: four cameras' active vertices, summed and
as a union. Writes ``benchmarks/results/cache.json``, ``cache.png``
(cumulative inserts at 2 x P) and ``cache_sizes.png`` (inserts against the
cache size). The default run takes about 3 minutes on a 2-core machine (the
first run also builds the three meshes into benchmarks/results/, ignored by
git: about 15 s).
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

import numpy as np

import caveclod
from caveclod import paths, wire
from caveclod.builder.version import made_by_this_code
from caveclod.v1 import caveclod_pb2 as pb
from caveclod.refine.activevertices import ActiveVertices
from caveclod.refine.cachedcamera import CachedCamera
from caveclod.refine.vertexcache import VertexCache, vertex_keys

RESULTS = Path(__file__).parent / "results"
FPS = 30
STRATEGIES = ("fa", "lru", "lru_pq")
TRAJECTORIES = ("circle", "rotate", "line")
OBJECT_TRAJECTORIES = ("circle", "swing", "rotate", "line")
PAPER_ROTATION = {"blob": "swing", "blob-backface": "swing"}   # ours that is the paper's trajectory B, where they differ
LABELS = {"fa": "FA", "lru": "LRU", "lru_pq": "LRU+PQ10%"}
STYLES = {"fa": "-", "lru": "-", "lru_pq": "--"}     # dashed: LRU+PQ often lies on LRU

# Lario, Pajarola & Tirado 2004: vertices inserted into video memory.
PAPER = {
    "table2_dragon_fastmesh": {
        "frames": 1000, "cache_slots": 2 ** 17, "model_vertices": 437645, "viewport": "800x800",
        "circle": {"fa": 1286367, "lru": 1068700, "lru_pq": 1030306},
        "rotate": {"fa": 1115502, "lru": 132966, "lru_pq": 134891},
        "line": {"fa": 260863, "lru": 122049, "lru_pq": 122049},
    },
    "table4_puget_sound_quadtin": {
        "frames": 3000, "cache_slots": 2 ** 16, "model_vertices": 2563548, "viewport": "1024x768",
        "circle": {"fa": 171873, "lru": 169928, "lru_pq": 169972},
        "rotate": {"fa": 302288, "lru": 286331, "lru_pq": 281707},
        "line": {"fa": 290747, "lru": 66453, "lru_pq": 66436},
    },
}


# -- meshes ------------------------------------------------------------------------------

def blob_source(subdivisions: int, seed: int = 2):
    """A closed scanned-style object: an icosphere, radius 100, displaced along its
    radius by three octaves of plane waves and a little scanner noise."""
    import trimesh
    rng = np.random.default_rng(seed)
    sphere = trimesh.creation.icosphere(subdivisions=subdivisions)
    p = sphere.vertices
    r = np.ones(len(p))
    for amplitude, frequency, waves in ((0.18, 1.5, 6), (0.05, 5.0, 12), (0.012, 18.0, 24)):
        k = rng.normal(size=(waves, 3))
        k /= np.linalg.norm(k, axis=1, keepdims=True)
        phase = rng.uniform(0, 2 * np.pi, waves)
        r += amplitude * np.sin(frequency * np.pi * p @ k.T + phase).mean(axis=1) * np.sqrt(waves) / 2
    r += rng.normal(0.0, 0.0015, len(p))
    return trimesh.Trimesh(p * r[:, None] * 100.0, sphere.faces, process=False)


def is_object(name: str) -> bool:
    return name.startswith("blob")


def load_mesh(name: str, args):
    """A mesh built once into benchmarks/results/ (ignored by git), as the other benchmarks do."""
    if is_object(name):
        path = RESULTS / f"blob_{args.blob_subdivisions}.cvc"
        build = lambda: caveclod.build(blob_source(args.blob_subdivisions), crease_angle=180.0)   # noqa: E731
    else:
        path = RESULTS / f"{name}_{args.terrain_size}.cvc"
        build = lambda: caveclod.build(name, size=args.terrain_size)    # noqa: E731
    if not made_by_this_code(path):           # absent, or built by other code: build it again
        print(f"building {path.name} ...", file=sys.stderr)
        RESULTS.mkdir(parents=True, exist_ok=True)
        build().save(path)
    return caveclod.load(path)


def setting(name: str, args) -> dict:
    """Viewport and frames: the paper's for an object (Table 2) or a terrain (Table 4);
    ``blob-backface`` culls back faces too (normal cones), the others the frustum only."""
    backface = name.endswith("-backface")
    if is_object(name):
        return {"width": 800, "height": 800, "frames": args.object_frames, "backface": backface}
    return {"width": 1024, "height": 768, "frames": args.terrain_frames, "backface": backface}


def swing(lo, hi, t: float, *, period: float = 8.0, degrees: float = 15.0) -> paths.Pose:
    """Small rotations round an object (the paper's Figure 9b, "the camera is pointing to the
    centre of the model"): the circle's eye swinging +-``degrees`` round the centre, looking at it."""
    phase = (degrees / 360.0) * np.sin(2.0 * np.pi * t / period)      # laps of a 1-second circle
    return paths.circle(lo, hi, 0, phase, seconds_per_lap=1.0)


def trajectories(name: str) -> tuple:
    return OBJECT_TRAJECTORIES if is_object(name) else TRAJECTORIES


def pose(trajectory: str, lo, hi, frame: int, frames: int) -> paths.Pose:
    t = frame / FPS
    if trajectory == "swing":
        return swing(lo, hi, t)
    if trajectory == "circle":
        return paths.circle(lo, hi, 0, t, seconds_per_lap=frames / FPS)          # one lap
    if trajectory == "line":
        return paths.line(lo, hi, 0, t, seconds=frames / FPS / 2)                # out and back
    return paths.rotate(lo, hi, 0, t)


def views(mesh, trajectory: str, s: dict) -> list:
    lo, hi = mesh.bounds()
    return [caveclod.View.from_pose(pose(trajectory, lo, hi, i, s["frames"]), width=s["width"], height=s["height"],
                                    fov_y=45.0, tolerance_px=1.0, backface=s["backface"]) for i in range(s["frames"])]


# -- one refinement run --------------------------------------------------------------------

def refine_resident(mesh, vs: list) -> dict:
    """Resident refinement, one update a frame: each frame's added/removed vertices and delta."""
    cam = mesh.new_camera()
    av = ActiveVertices(mesh.n_vertices, cam.triangles())
    frames, peak, t_refine, t_track = [], av.count, [], []
    for v in vs:
        t0 = time.perf_counter()
        d = cam.update(v)
        t1 = time.perf_counter()
        added, removed = av.apply(d)
        t2 = time.perf_counter()
        t_refine.append(t1 - t0)
        t_track.append(t2 - t1)
        peak = max(peak, av.count)
        frames.append((added, removed, d))
    base = np.flatnonzero(ActiveVertices(mesh.n_vertices, mesh.new_camera().triangles()).refs).astype(np.int32)
    return {"base": base, "frames": frames, "peak": peak, "refine_us": t_refine, "track_us": t_track,
            "tolerance_max": 1.0, "updates": len(vs)}


def refine_fitted(mesh, vs: list, slots: int) -> dict:
    """Refinement fitted to ``slots`` (CachedCamera, LRU): the events are the same for every strategy."""
    cc = CachedCamera(mesh.new_camera(), slots, "lru")
    base = cc.cache.active_slots()[1].copy()
    frames, tol, updates, own = [], 1.0, 0, 0
    for v in vs:
        cd = cc.update(v)
        frames.append((cd.added, cd.removed, cd.delta))
        tol = max(tol, cd.tolerance_px)
        updates += cd.updates
        own += cd.inserted
    return {"base": np.sort(base), "frames": frames, "peak": None, "tolerance_max": tol, "updates": updates,
            "lru_inserted_check": own + len(base)}


# -- replaying a run through each strategy ------------------------------------------------

class FrameSize:
    """Serialized bytes of the frame caveclod serve sends for one camera's update, as
    ``caveclod.wire.frame_parts`` encodes it: resident, or with a strategy's vertex writes.
    The resident frame is encoded once; a strategy's writes are set on it, measured and
    cleared again (a frame over 1 MiB, split into parts, is encoded whole each time)."""

    def __init__(self, delta):
        self.surfaces = [wire.Surface(m, d.count, d.slots, d.tris, 0xFFFFFFFF) for m, d in sorted(delta.surfaces.items())]
        self.stats = {"splits": delta.splits, "collapses": delta.collapses, "update_us": 1500, "active_faces": 20000,
                      "budget_exhausted": False, "pose_age_us": 9000, "updates": 1}
        self.parts = self._parts(None, None)
        self.resident = sum(p.ByteSize() for p in self.parts)
        self.array_bytes = sum(16 * len(s.slots) for s in self.surfaces)

    def _parts(self, writes, hits):
        stats = dict(self.stats)
        if hits is not None:
            stats.update(cache_hits=hits, cache_inserts=0 if writes is None else len(writes.slots),
                         cache_tolerance_px=1.0)
        cam = wire.CameraFrameData(camera=0, pose_seq=1000, surfaces=self.surfaces, stats=stats, vertices=writes)
        return [pb.ServerMessage.FromString(b) for b in wire.frame_parts(1000, 1000, 0, [cam])]

    def cached(self, writes: wire.SlotWrites | None, hits: int) -> int:
        k = 0 if writes is None else len(writes.slots)
        if len(self.parts) > 1 or self.array_bytes + k * (writes.row_bytes + 4 if k else 0) > wire.MAX_CHUNK_BYTES:
            return sum(p.ByteSize() for p in self._parts(writes, hits))
        entry = self.parts[0].frame.cameras[0]
        entry.stats.cache_hits, entry.stats.cache_inserts, entry.stats.cache_tolerance_px = hits, k, 1.0
        if writes is not None:
            entry.vertices.CopyFrom(wire.encode_slot_writes(writes))
        n = self.parts[0].ByteSize()
        entry.ClearField("vertices")
        entry.stats.cache_hits, entry.stats.cache_inserts, entry.stats.cache_tolerance_px = 0, 0, 0.0
        return n


def replay(run: dict, mesh, slots: int, strategy: str, keys, row_blocks) -> dict:
    """Feed a run's added/removed vertices to a fresh cache; count inserts, hits, bytes."""
    cache = VertexCache(slots, mesh.n_vertices, strategy, None, keys if strategy == "lru_pq" else None)
    cache.update(run["base"], np.zeros(0, np.int32))
    inserted = [len(run["base"])]
    hits, activated, vertex_bytes, total_bytes, cache_us = 0, 0, 0, 0, []
    for (added, removed, delta), size in zip(run["frames"], run["sizes"]):
        t0 = time.perf_counter()
        s, v, h = cache.update(added, removed)
        cache_us.append(time.perf_counter() - t0)
        inserted.append(len(s))
        hits += h
        activated += len(added)
        writes = None
        if len(s):
            writes = wire.SlotWrites(s, [b[: len(s)] for b in row_blocks], 0xFFFFFFFF)
            vertex_bytes += wire.encode_slot_writes(writes).ByteSize()
        total_bytes += size.cached(writes, h)
    n = len(run["frames"])
    # inserted[0] is the base mesh, inserted[1] the first frame's refinement up from it: the
    # same for every strategy (the cache starts empty); what follows is where they differ.
    return {"inserted": int(sum(inserted)), "inserted_after_first_frame": int(sum(inserted[2:])),
            "inserted_per_frame_mean": round(sum(inserted[1:]) / n, 2),
            "inserted_per_frame_max": int(max(inserted[1:])), "hit_rate": round(hits / activated, 4) if activated else None,
            "vertex_bytes_per_frame": round(vertex_bytes / n, 1), "frame_bytes_per_frame": round(total_bytes / n, 1),
            "cache_us_p50": round(1e6 * statistics.median(cache_us), 1), "per_frame": inserted}


def measure(mesh, name: str, args, keys) -> tuple[dict, list]:
    s = setting(name, args)
    print(f"{name}: {mesh.n_faces:,} faces, {mesh.n_vertices:,} vertices, {s['frames']} frames at "
          f"{s['width']}x{s['height']}", file=sys.stderr)
    vs = {t: views(mesh, t, s) for t in trajectories(name)}
    resident = {t: refine_resident(mesh, vs[t]) for t in trajectories(name)}
    peak = max(r["peak"] for r in resident.values())
    base_vertices = len(resident["circle"]["base"])
    sizes = sorted({max(int(np.ceil(f * peak / 64) * 64), base_vertices) for f in args.sizes})
    paperlike = min(sizes, key=lambda n: abs(n - 2 * peak))          # the paper's: about twice the need
    colors = len(mesh.vertex_colors) > 0
    row_blocks = [np.zeros((peak * 2 + 64, 3), "<f4"), np.zeros((peak * 2 + 64, 3), "<f4"),
                  np.zeros((peak * 2 + 64, 2), "<f4")] + ([np.zeros((peak * 2 + 64, 4), np.uint8)] if colors else [])
    row_bytes = 32 + 4 * colors
    runs, curves = [], []
    for t in trajectories(name):
        r = resident[t]
        r["sizes"] = [FrameSize(d) for _, _, d in r["frames"]]
        resident_bytes = [size.resident for size in r["sizes"]]
        activated = len(r["base"]) + sum(len(a) for a, _, _ in r["frames"])
        distinct = len(set(r["base"].tolist()).union(*(set(a.tolist()) for a, _, _ in r["frames"])))
        for slots in sizes:
            fits = slots >= r["peak"]
            if fits:
                run = r
            else:
                run = refine_fitted(mesh, vs[t], slots)
                run["sizes"] = [FrameSize(d) for _, _, d in run["frames"]]
            out = {"mesh": name, "trajectory": t, "slots": slots, "slots_over_peak": round(slots / peak, 2),
                   "fits_every_frame": fits, "frames": len(vs[t]), "peak_active_vertices": r["peak"],
                   "tolerance_px_max": round(run["tolerance_max"], 2),
                   "updates_per_frame": round(run["updates"] / len(vs[t]), 2),
                   "vertices_activated": activated if fits else None, "distinct_vertices": distinct if fits else None,
                   # churn: vertices that became active per frame after the first (what FA reinserts at worst)
                   "activated_per_frame_after_first": round(statistics.mean(len(a) for a, _, _ in run["frames"][1:]), 1)
                   if len(run["frames"]) > 1 else None,
                   "resident_frame_bytes_per_frame": round(statistics.mean(resident_bytes), 1),
                   "resident_vertex_buffer_bytes": mesh.n_vertices * row_bytes, "strategies": {}}
            for strategy in STRATEGIES:
                res = replay(run, mesh, slots, strategy, keys, row_blocks)
                if strategy == "lru" and not fits:
                    assert res["inserted"] == run["lru_inserted_check"], "replay differs from the CachedCamera"
                if slots == paperlike:
                    curves.append((name, t, slots, strategy, res["per_frame"]))
                del res["per_frame"]
                # Against resident mode: its frames alone, and with the vertex buffer it downloads first.
                res["frame_bytes_over_resident"] = round(res["frame_bytes_per_frame"] / statistics.mean(resident_bytes), 2)
                res["bytes_over_resident_with_vertex_buffer"] = round(
                    res["frame_bytes_per_frame"] * len(vs[t]) / (sum(resident_bytes) + mesh.n_vertices * row_bytes), 3)
                out["strategies"][strategy] = res
            if fits:
                out["refine_us_p50"] = round(1e6 * statistics.median(r["refine_us"]), 1)
                out["active_vertex_tracking_us_p50"] = round(1e6 * statistics.median(r["track_us"]), 1)
            runs.append(out)
            st = out["strategies"]
            print(f"  {t:6s} {slots:7,} slots{'' if fits else ' (coarsened)'}: inserted FA {st['fa']['inserted']:,} "
                  f"LRU {st['lru']['inserted']:,} LRU+PQ {st['lru_pq']['inserted']:,}", file=sys.stderr)
    info = {"faces": mesh.n_faces, "vertices": mesh.n_vertices, "base_vertices": base_vertices,
            "viewport": f"{s['width']}x{s['height']}", "fov_y": 45.0, "tolerance_px": 1.0, "frames": s["frames"],
            "backface_culling": s["backface"],
            "peak_active_vertices": {t: resident[t]["peak"] for t in trajectories(name)}, "P": peak, "sizes": sizes}
    return {"mesh": info, "runs": runs}, curves


# -- caches per camera or per session ------------------------------------------------------------

def sharing(mesh, name: str, args) -> dict:
    """Four cameras' active vertices each frame: their sum (caches per camera) and their union (one
    cache per session). Terrains: the flyover over the four quadrants (Kram & Shaw's cameras A-D);
    the object: circles a quarter-turn apart (four sides of it)."""
    s = setting(name, args)
    lo, hi = mesh.bounds()
    cams = [mesh.new_camera() for _ in range(4)]
    avs = [ActiveVertices(mesh.n_vertices, c.triangles()) for c in cams]
    frames = min(s["frames"], 600)
    ratios, sums, unions = [], [], []
    for i in range(frames):
        for k, (cam, av) in enumerate(zip(cams, avs)):
            p = paths.circle(lo, hi, k, i / FPS, seconds_per_lap=frames / FPS) if is_object(name) \
                else paths.flyover(lo, hi, k, i / FPS)
            av.apply(cam.update(caveclod.View.from_pose(p, width=s["width"] // 2, height=s["height"] // 2,
                                                        fov_y=45.0, tolerance_px=1.0, backface=s["backface"])))
        if i >= FPS:
            total = sum(av.count for av in avs)
            union = int(np.count_nonzero(np.logical_or.reduce([av.refs > 0 for av in avs])))
            sums.append(total)
            unions.append(union)
            ratios.append(union / total)
    return {"cameras": 4, "paths": "circle, a quarter-turn apart" if is_object(name) else "flyover (quadrants)",
            "frames": frames, "sum_of_active_vertices_mean": round(statistics.mean(sums)),
            "union_of_active_vertices_mean": round(statistics.mean(unions)),
            "union_over_sum_mean": round(statistics.mean(ratios), 3), "union_over_sum_min": round(min(ratios), 3),
            "sum_peak": max(sums), "union_peak": max(unions)}


# -- the paper beside ours -------------------------------------------------------------------------

def comparison(results: dict) -> dict:
    out = {}
    for name, r in results.items():
        paperlike = sorted(r["mesh"]["sizes"], key=lambda n: abs(n - 2 * r["mesh"]["P"]))[0]
        rows = {run["trajectory"]: run["strategies"] for run in r["runs"] if run["slots"] == paperlike}
        out[name] = {"slots": paperlike, "paper_rotation_is": PAPER_ROTATION.get(name, "rotate"), **{t: {
            "fa_over_lru": round(rows[t]["fa"]["inserted"] / rows[t]["lru"]["inserted"], 3),
            "lru_pq_over_lru": round(rows[t]["lru_pq"]["inserted"] / rows[t]["lru"]["inserted"], 4),
            "fa_over_lru_after_first_frame": _ratio(rows[t]["fa"]["inserted_after_first_frame"],
                                                    rows[t]["lru"]["inserted_after_first_frame"]),
            "inserted": {k: v["inserted"] for k, v in rows[t].items()},
            "inserted_after_first_frame": {k: v["inserted_after_first_frame"] for k, v in rows[t].items()}}
            for t in trajectories(name)}}
    for key, table in PAPER.items():
        out[key] = {t: {"fa_over_lru": round(table[t]["fa"] / table[t]["lru"], 3),
                        "lru_pq_over_lru": round(table[t]["lru_pq"] / table[t]["lru"], 4)} for t in TRAJECTORIES}
    return out


def _ratio(a: int, b: int) -> float | None:
    return round(a / b, 3) if b else None


def plot(curves: list, results: dict) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import FuncFormatter, NullLocator
    names = list(results)
    fig, axes = plt.subplots(len(names), 4, figsize=(15, 3.2 * len(names)), squeeze=False)
    for row, name in enumerate(names):
        for col in range(len(trajectories(name)), 4):
            axes[row][col].axis("off")
        for col, t in enumerate(trajectories(name)):
            ax = axes[row][col]
            for (n, tt, slots, strategy, per_frame) in curves:
                if n == name and tt == t:
                    ax.plot(np.cumsum(per_frame), STYLES[strategy], label=LABELS[strategy])
                    ax.set_title(f"{name}, {t}: {slots:,} slots (about 2 x P)", fontsize=9)
            ax.set_xlabel("frame")
            ax.set_ylabel("vertices inserted (cumulative)")
            ax.grid(alpha=0.3)
            ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(RESULTS / "cache.png", dpi=100)
    plt.close(fig)
    fig, axes = plt.subplots(len(names), 4, figsize=(15, 3.2 * len(names)), squeeze=False)
    for row, name in enumerate(names):
        for col in range(len(trajectories(name)), 4):
            axes[row][col].axis("off")
        for col, t in enumerate(trajectories(name)):
            ax = axes[row][col]
            runs = [r for r in results[name]["runs"] if r["trajectory"] == t]
            big = results[name]["mesh"]["P"]
            x = [r["slots"] / big for r in runs]
            for k, strategy in enumerate(STRATEGIES):
                y = [r["strategies"][strategy]["inserted"] for r in runs]
                line, = ax.plot(x, y, "-", label=LABELS[strategy])
                # Hollow markers: sizes below this trajectory's peak, where the camera was coarsened to fit.
                for xi, yi, r in zip(x, y, runs):
                    ax.plot(xi, yi, "o", color=line.get_color(), mfc=line.get_color() if r["fits_every_frame"] else "white")
            ax.axvline(results[name]["mesh"]["peak_active_vertices"][t] / big, ls="--", lw=0.8, color="grey")
            ax.set_xscale("log")
            ax.xaxis.set_minor_locator(NullLocator())
            ax.set_xticks(sorted(set(x)), [f"{v:.2g}" for v in sorted(set(x))])
            ax.yaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:,.0f}"))
            ax.set_title(f"{name}, {t} (P = {big:,}; dashed: this path's peak)", fontsize=8)
            ax.set_xlabel("cache slots / P (hollow: coarsened to fit)", fontsize=8)
            ax.set_ylabel("vertices inserted")
            ax.grid(alpha=0.3)
            ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(RESULTS / "cache_sizes.png", dpi=100)
    plt.close(fig)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--meshes", default="default,blob,blob-backface,rough")
    parser.add_argument("--sizes", default="0.75,1,2,4", help="cache sizes as multiples of the frame peak P")
    parser.add_argument("--object-frames", type=int, default=1000)
    parser.add_argument("--terrain-frames", type=int, default=3000)
    parser.add_argument("--terrain-size", type=int, default=512)
    parser.add_argument("--blob-subdivisions", type=int, default=7)
    args = parser.parse_args()
    args.sizes = [float(x) for x in args.sizes.split(",")]
    started = time.perf_counter()
    results, curves, shared = {}, [], {}
    for name in args.meshes.split(","):
        mesh = load_mesh(name, args)
        keys = vertex_keys(mesh)
        results[name], c = measure(mesh, name, args, keys)
        curves += c
        shared[name] = sharing(mesh, name, args)
        print(f"  sharing: union / sum of 4 cameras' vertices {shared[name]['union_over_sum_mean']}", file=sys.stderr)
    out = {"command": "python benchmarks/cache.py " + " ".join(sys.argv[1:]), "fps": FPS,
           "trajectories": {"circle": "one lap round the centre, looking at it",
                            "rotate": "fixed eye, view swinging +-15 degrees every 8 s (the paper's Figure 12b)",
                            "swing": "object only: the eye swinging +-15 degrees round the centre every 8 s, "
                                     "looking at it (the paper's Figure 9b, 'small rotations')",
                            "line": "straight out and back (object: 2 to 0.6 extents from the centre; terrain: "
                                    "across it 0.1 extent above the top)"},
           "results": results, "comparison": comparison(results), "paper": PAPER, "sharing": shared,
           "seconds": round(time.perf_counter() - started, 1)}
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / "cache.json").write_text(json.dumps(out, indent=2) + "\n")
    plot(curves, results)
    print(json.dumps(out["comparison"], indent=2))


if __name__ == "__main__":
    main()
