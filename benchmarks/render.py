"""The GPU renderer on a flyover: bytes uploaded patched vs whole, frame times.

    python benchmarks/render.py [--terrain default] [--size 256] [--cameras 4] [--seconds 10]

Cameras fly the paper's flyover at 30 Hz over a built-in terrain, refined at
1 px for their quadrant of a 1280x720 image (60 degree field of view). Each
frame's deltas go to two renderers: ``patched`` applies the slot writes in
place, ``whole`` re-uploads every index buffer from slot 0 (what a client
without patching would do). Reported: index bytes and write calls per frame
for both and their ratio, GPU-side copies when buffers grew, the time to
apply a frame and to render it (all cameras, plain and wireframe, pixels read
back) with whatever OpenGL is here (llvmpipe on the project's machines), and
1-camera 1280x720 times: rendered, drawn without read-back, and rendered
with every triangle of the mesh. Writes ``benchmarks/results/render.json``
and ``render_sheet.png`` (frames of the flyover).
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from pathlib import Path

import caveclod
from caveclod.builder.version import made_by_this_code
from caveclod.paths import flyover
from caveclod.render import Renderer, Vertices, contact_sheet, create_context, quadrants, save_png

RESULTS = Path(__file__).parent / "results"
FPS = 30
WIDTH, HEIGHT = 1280, 720


def load_mesh(name: str, size: int):
    """A built-in, built once into benchmarks/results/ (as refine.py does)."""
    path = RESULTS / f"{name}_{size}.cvc"
    if not made_by_this_code(path):           # absent, or built by other code: build it again
        path.parent.mkdir(parents=True, exist_ok=True)
        caveclod.build(name, size=size).save(path)
    return caveclod.load(path)


def feed(renderer, camera, delta) -> None:
    for material, d in delta.surfaces.items():
        renderer.apply(camera, material, d.count, d.tris, slots=d.slots)


def upload_whole(renderer, camera, cam) -> None:
    renderer.reset(camera)
    for material, tris in cam.triangles().items():
        renderer.apply(camera, material, len(tris), tris)


def percentiles(values) -> dict:
    ordered = sorted(values)
    return {"p50": statistics.median(ordered), "p90": ordered[int(0.9 * (len(ordered) - 1))]}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--terrain", default="default")
    parser.add_argument("--size", type=int, default=256)
    parser.add_argument("--cameras", type=int, default=4)
    parser.add_argument("--seconds", type=float, default=10.0)
    args = parser.parse_args()

    mesh = load_mesh(args.terrain, args.size)
    lo, hi = mesh.bounds()
    vertices = Vertices(mesh.vertex_positions, mesh.vertex_normals, mesh.vertex_uvs,
                        mesh.vertex_colors if len(mesh.vertex_colors) else None)
    ctx = create_context()
    patched = Renderer(WIDTH, HEIGHT, vertices, mesh.materials, cameras=args.cameras, bounds=(lo, hi), ctx=ctx)
    whole = Renderer(WIDTH, HEIGHT, vertices, mesh.materials, cameras=args.cameras, bounds=(lo, hi), ctx=ctx)
    cams = [mesh.new_camera() for _ in range(args.cameras)]
    sizes = [(w, h) for _, _, w, h in quadrants(WIDTH, HEIGHT, args.cameras)]
    for k, cam in enumerate(cams):
        feed(patched, k, cam.keyframe())
    frames = int(args.seconds * FPS)
    apply_s, render_s, wire_s, sheet = [], [], [], []
    bytes_p, bytes_w, writes_p, writes_w, triangles = [], [], [], [], []
    for frame in range(frames):
        poses = [flyover(lo, hi, k, frame / FPS) for k in range(args.cameras)]
        deltas = [cam.update(caveclod.View.from_pose(pose, width=w, height=h, tolerance_px=1.0))
                  for cam, pose, (w, h) in zip(cams, poses, sizes)]
        before = (patched.stats.index_bytes, patched.stats.index_writes, whole.stats.index_bytes,
                  whole.stats.index_writes)
        t0 = time.perf_counter()
        for k, delta in enumerate(deltas):
            feed(patched, k, delta)
        apply_s.append(time.perf_counter() - t0)
        for k, cam in enumerate(cams):
            upload_whole(whole, k, cam)
        t0 = time.perf_counter()
        image = patched.render(poses)
        render_s.append(time.perf_counter() - t0)
        if frame % 10 == 0:
            t0 = time.perf_counter()
            patched.render(poses, wireframe=True)
            wire_s.append(time.perf_counter() - t0)
        if frame >= FPS:            # the first second refines up from the base mesh
            bytes_p.append(patched.stats.index_bytes - before[0])
            writes_p.append(patched.stats.index_writes - before[1])
            bytes_w.append(whole.stats.index_bytes - before[2])
            writes_w.append(whole.stats.index_writes - before[3])
            triangles.append(sum(cam.n_faces for cam in cams))
        if frame % (frames // 6) == frames // 12:
            sheet.append(image[::3, ::3])      # a third of the size: the sheet stays small

    single = Renderer(WIDTH, HEIGHT, vertices, mesh.materials, cameras=1, bounds=(lo, hi), ctx=ctx)
    one = mesh.new_camera()
    single_s = []
    for frame in range(FPS):
        pose = flyover(lo, hi, 0, frame / FPS)
        feed(single, 0, one.update(caveclod.View.from_pose(pose, width=WIDTH, height=HEIGHT, tolerance_px=1.0)))
        t0 = time.perf_counter()
        single.render([pose])
        single_s.append(time.perf_counter() - t0)
    single_triangles = one.n_faces
    draw_s = []                     # the same without reading pixels back (what a window pays)
    for _ in range(10):
        t0 = time.perf_counter()
        single.draw([pose])
        ctx.finish()
        draw_s.append(time.perf_counter() - t0)
    full = mesh.new_camera()        # every original triangle: the renderer's triangle-bound end
    full.update(caveclod.View.from_pose(pose, width=WIDTH, height=HEIGHT, tolerance_px=0.0, cull=False))
    upload_whole(single, 0, full)
    full_s = []
    for _ in range(6):
        t0 = time.perf_counter()
        single.render([pose])
        full_s.append(time.perf_counter() - t0)

    ms = lambda values: {k: round(v * 1e3, 2) for k, v in percentiles(values).items()}   # noqa: E731
    result = {
        "mesh": f"{args.terrain} --size {args.size}", "faces": mesh.n_faces, "vertices": mesh.n_vertices,
        "cameras": args.cameras, "frames": frames, "image": f"{WIDTH}x{HEIGHT}", "gl_renderer": ctx.info["GL_RENDERER"],
        "active_triangles_per_frame": round(statistics.mean(triangles)),
        "index_bytes_per_frame": {"patched": round(statistics.mean(bytes_p)), "whole": round(statistics.mean(bytes_w))},
        "index_writes_per_frame": {"patched": round(statistics.mean(writes_p), 1),
                                   "whole": round(statistics.mean(writes_w), 1)},
        "whole_over_patched_bytes": round(sum(bytes_w) / max(sum(bytes_p), 1), 1),
        "patched_totals": vars(patched.stats).copy(),
        "apply_ms": ms(apply_s[FPS:]),
        "render_ms": ms(render_s[FPS:]),
        "render_wireframe_ms": ms(wire_s[3:]),
        "render_1_camera_ms": ms(single_s[5:]), "render_1_camera_triangles": single_triangles,
        "draw_1_camera_no_readback_ms": ms(draw_s[2:]),
        "render_all_faces_ms": ms(full_s[1:]), "render_all_faces_triangles": full.n_faces,
    }
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / "render.json").write_text(json.dumps(result, indent=2) + "\n")
    save_png(RESULTS / "render_sheet.png", contact_sheet(sheet, columns=3,
                                                         labels=[f"frame {frames // 12 + i * (frames // 6)}"
                                                                 for i in range(len(sheet))]))
    print(json.dumps(result, indent=2))
    for renderer in (patched, whole, single):
        renderer.release()
    ctx.release()


if __name__ == "__main__":
    main()
