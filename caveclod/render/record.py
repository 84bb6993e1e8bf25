"""``caveclod render``: fly a session's cameras through a server and write the images.

    caveclod render --target HOST:PORT [--mesh NAME] --cameras N --trajectory PATH
                    --frames K [--size WxH] [--wireframe] --out DIR

writes ``DIR/frame_0000.png ...`` (the quadrant images), ``DIR/animation.gif``
(all frames, at most 640 pixels wide: it opens in any browser or image
viewer) and ``DIR/render.json`` (what the flight cost: operations per
camera-second, bytes per frame, pose -> frame latency, divergences).
:func:`record` is the loop, shared with ``caveclod demo``.
"""

from __future__ import annotations

import json
import math
import os
import sys
import time
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..vertexpack import check_position_bits
from ..wire import strategy_name
from .camera import quadrants
from .flight import FlightError, fly
from .images import save_animation, save_png
from .session import SessionRenderer

ANIMATION_WIDTH = 640       # an animation's frames are shrunk to this width at most
ANIMATION_FPS = 15.0        # and taken at most this often: GIF files grow with every frame
ANIMATION_NAME = "animation.gif"


def parse_size(text: str) -> tuple[int, int]:
    """``"1280x720"`` -> (1280, 720); InputError naming the expected form otherwise."""
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise InputError(f"--size must be WIDTHxHEIGHT in pixels, e.g. 1280x720; got {text!r}") from None
    if not (16 <= w <= 8192 and 16 <= h <= 8192):
        raise InputError(f"--size must be 16 to 8192 pixels each way, got {w}x{h}")
    return w, h


def morph_ms(args) -> float:
    """``--morph-ms`` checked (and ``--morph-speed``): milliseconds, 0 (or absent) for no geomorphs."""
    morph = getattr(args, "morph_ms", 0.0) or 0.0
    if not (morph >= 0 and math.isfinite(morph)):     # NaN turned morphs off, inf never ended them
        raise InputError(f"--morph-ms must be a finite number of milliseconds, at least 0 (0: no geomorphs), "
                         f"got {morph:g}")
    speed = getattr(args, "morph_speed", None)
    if speed is not None and not (speed > 0 and math.isfinite(speed)):
        raise InputError(f"--morph-speed must be a positive number of pixels a second, got {speed:g}")
    return morph


def cache_options(args) -> dict:
    """``client.session`` keywords for ``--cache-vertices N [--cache-strategy S] [--cache-pq-fraction F]``
    and ``--vertex-encoding E [--position-bits B]``."""
    n, strategy, fraction = args.cache_vertices, args.cache_strategy, args.cache_pq_fraction
    bits = getattr(args, "position_bits", None)
    if bits is not None:
        try:
            check_position_bits(bits)
        except ValueError as exc:
            raise InputError(f"--{str(exc).replace('_', '-')}") from None
    morph = morph_ms(args)
    morphs = morph > 0 and getattr(args, "vertex_encoding", "packed") == "packed"
    # Geomorphs download the morph targets, which is what linked op streams read: take them.
    encoding = {"vertex_encoding": getattr(args, "vertex_encoding", "packed"), "position_bits": bits,
                "morph_targets": morphs, "frame_encoding": "linked" if morphs else "ops"}
    if n is None:
        if strategy is not None or fraction is not None:
            raise InputError("--cache-strategy and --cache-pq-fraction need --cache-vertices N (slots per camera)")
        return encoding
    if n < 1:
        raise InputError(f"--cache-vertices must be at least 1 (slots per camera), got {n}")
    return {"cache_vertices": n, "cache_strategy": strategy, "cache_pq_fraction": fraction, **encoding}


def shrink(image: np.ndarray, width: int = ANIMATION_WIDTH) -> np.ndarray:
    """``image`` (h, w, 3) scaled down by a whole factor until it is at most ``width`` wide (box filter)."""
    from PIL import Image
    f = -(-image.shape[1] // width)
    if f <= 1:
        return image
    return np.asarray(Image.fromarray(image).reduce(f))


def record(session, out: Path, *, size: tuple[int, int], trajectory: str, frames: int, fps: float = 30.0,
           wireframe: bool = False, verify: bool = True, keep_every: int = 1, progress: bool = True,
           animation: Path | None = None, animation_width: int = ANIMATION_WIDTH,
           wireframe_still: Path | None = None, morph_ms: float = 0.0,
           morph_speed: float | None = None) -> tuple[dict, list]:
    """Fly ``session`` along ``trajectory`` for ``frames`` frames; write the images into ``out``.

    Args:
        session: an open blocking :class:`caveclod.client.Session`.
        size: (width, height) of the quadrant image.
        verify: compare the GPU buffers (and vertex slots) with the client library's after every frame.
        keep_every: write every n-th frame as a PNG (the animation has them all).
        animation: where the animation goes (default ``out / "animation.gif"``).
        animation_width: the animation's frames are shrunk to at most this width.
        wireframe_still: also draw the last frame with the wireframe overlay, as a PNG here.
        morph_ms: geomorph duration (the session opened with ``morph_targets=True``); 0: none.
        morph_speed: None, or geomorphs' pixels a second (each at most ``morph_ms``).

    Returns:
        ``(summary, frames)``: the figures ``render.json`` holds, and every
        frame as shrunk for the animation ((h, w, 3) uint8 each).
    """
    out.mkdir(parents=True, exist_ok=True)
    for old in out.glob("frame_[0-9][0-9][0-9][0-9].png"):
        old.unlink()                  # frames of an earlier, longer run would mix in
    n = int(session.info.cameras)
    latency, ops, nbytes, faces, written, small, draw_ms = [], [], [], [], [], [], []
    verified, inserted = 0, 0
    started = time.perf_counter()
    with SessionRenderer(session, *size, morph_ms=morph_ms, morph_speed=morph_speed) as view:
        for rec in fly(session, view, trajectory, frames, fps=fps, wireframe=wireframe, verify=verify):
            latency += [v for v in rec.latency_ms if v is not None]
            ops.append(rec.operations)
            faces.append(rec.active_faces)
            nbytes.append(rec.nbytes)
            verified += verify
            small.append(shrink(rec.image, animation_width))
            if rec.index % keep_every == 0 or rec.index == frames - 1:
                written.append(save_png(out / f"frame_{rec.index:04d}.png", rec.image).name)
            draw_ms.append(rec.draw_ms)
            inserted += sum(cam.vertices_written for f in rec.frames for cam in f.cameras.values())
            if progress and (rec.index % 30 == 29 or rec.index == frames - 1):
                print(f"render: frame {rec.index + 1}/{frames}, {sum(rec.active_faces):,} faces, "
                      f"latency {np.median(latency) if latency else float('nan'):.1f} ms (p50 so far)",
                      file=sys.stderr, flush=True)
        stats = view.renderer.stats
        if wireframe_still is not None:
            save_png(wireframe_still, view.render(rec.poses, wireframe=True))
    animation = out / ANIMATION_NAME if animation is None else Path(animation)
    step = max(int(round(fps / ANIMATION_FPS)), 1)
    save_animation(animation, small[::step], fps=fps / step)
    ops = np.asarray(ops, dtype=np.float64)
    lat = np.asarray(latency)
    seconds = frames / fps
    summary = {
        "frames": frames, "cameras": n, "trajectory": trajectory, "path_seconds": round(seconds, 2),
        "image": f"{size[0]}x{size[1]}", "quadrant": list(quadrants(*size, n)[0][2:]),
        "mesh": session.info.mesh.name, "mesh_faces": int(session.info.mesh.faces),
        "tolerance_px": round(float(session.info.options.tolerance_px), 3),
        # Frame 0 refines every camera up from the base mesh: the rates leave it out.
        "operations_per_camera_second": round(float(ops[1:].sum() / max(seconds - 1 / fps, 1e-9) / n), 1)
        if frames > 1 else None,
        "operations_per_camera_second_by_camera": [round(float(v), 1) for v in
                                                   ops[1:].sum(axis=0) / max(seconds - 1 / fps, 1e-9)]
        if frames > 1 else None,
        "first_frame_operations": int(ops[0].sum()),
        "active_faces_last_frame": [int(v) for v in faces[-1]],
        "bytes_per_frame": {"median": float(np.median(nbytes)), "mean": round(float(np.mean(nbytes)), 1),
                            "first": int(nbytes[0])},
        "latency_ms": {k: round(float(np.percentile(lat, q)), 2) if len(lat) else None
                       for k, q in (("p50", 50), ("p90", 90), ("p99", 99), ("max", 100))},
        "divergences": session.protocol.divergences,
        # Cache mode: N vertex slots per camera, and the vertices the frames wrote into them.
        "cache_vertices": int(session.info.cache_vertices) or None,
        "cache_strategy": strategy_name(session.info.cache_strategy), "vertices_inserted": inserted,
        "bad_frames": session.protocol.bad_frames, "resumes": session.protocol.resumes,
        # Frames after which every GPU index buffer, read back, equalled the
        # client library's (a difference stops the flight with FlightError).
        "gpu_buffers_verified_frames": verified,
        "gpu_index_bytes_uploaded": stats.index_bytes, "gpu_vertex_bytes_uploaded": stats.vertex_bytes,
        "render_ms_p50": round(float(np.median(draw_ms)), 1),
        "wall_seconds": round(time.perf_counter() - started, 1),
        "frames_written": written, "animation": animation.name,
        "series": {"operations": ops.astype(int).tolist(), "bytes": nbytes, "latency_ms": [round(v, 3) for v in latency]},
    }
    return summary, small


def main(args) -> int:
    """``caveclod render``: exit 0 when every frame arrived intact, 1 on divergences."""
    from ..client import Client, SessionEnded
    size = parse_size(args.size)
    if not 1 <= args.cameras <= 4:
        raise InputError(f"--cameras must be 1 to 4 (the quadrants of one image), got {args.cameras}")
    if args.frames < 1:
        raise InputError(f"--frames must be at least 1, got {args.frames}")
    if not 0.01 <= args.fps <= 1000:     # 0 divided, inf and 1e-9 overflowed, NaN reached the server
        raise InputError(f"--fps must be from 0.01 to 1000 frames a second, got {args.fps:g}")
    cache = cache_options(args)
    qw, qh = quadrants(*size, args.cameras)[0][2:]
    token = args.token or os.environ.get("CAVECLOD_TOKEN")
    out = Path(args.out)
    try:
        with Client(args.target, token=token, tls_ca=args.tls_ca, cache_dir=args.cache_dir) as client:
            mesh = pick_mesh(client, args.mesh, args.target)
            with client.session(mesh, cameras=args.cameras, width=qw, height=qh, fov_y=args.fov,
                                tolerance_px=args.tolerance, prune=False if args.no_prune else None,
                                strict_bound=True if getattr(args, "strict_bound", False) else None,
                                **cache) as session:
                summary, _ = record(session, out, size=size, trajectory=args.trajectory, frames=args.frames,
                                 fps=args.fps, wireframe=args.wireframe, morph_ms=args.morph_ms,
                                 morph_speed=args.morph_speed)
    except SessionEnded as exc:
        raise InputError(f"{args.target}: the session ended: {exc}") from None
    except FlightError as exc:
        raise InputError(str(exc)) from None
    (out / "render.json").write_text(json.dumps(summary, indent=1))
    print(f"wrote {len(summary['frames_written'])} frames, {ANIMATION_NAME} and render.json to {out}/: "
          f"latency p50 {summary['latency_ms']['p50']} ms, {summary['operations_per_camera_second']} "
          f"operations per camera-second, {summary['divergences']} divergences")
    return 1 if summary["divergences"] else 0


def pick_mesh(client, name: str | None, target: str) -> str:
    """``name``, checked against what the server serves, or its first mesh."""
    import grpc
    try:
        names = [m.name for m in client.list_meshes()]
    except grpc.RpcError as exc:
        raise InputError(f"cannot list the meshes of {target}: {exc.code().name}: {exc.details()}; "
                         "is 'caveclod serve' running there?") from None
    if not names:
        raise InputError(f"{target} serves no meshes")
    if name is not None and name not in names:
        raise InputError(f"{target} has no mesh {name!r}; it serves {', '.join(names)}")
    return name or names[0]
