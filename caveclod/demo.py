"""``caveclod demo`` (``make demo``): the whole product, from nothing, through the real service.

1. Builds the built-in default terrain (or reuses ``DIR/default.cvc``).
2. Starts ``caveclod serve`` on it as a subprocess, on 127.0.0.1 and a free port.
3. Opens one 4-camera session over gRPC with the client library and flies
   the cameras A-D over the four quadrants of the terrain (the paper's
   flyover; :func:`caveclod.paths.flyover`), one pose per camera per frame.
4. Renders every frame with the GPU renderer (the vertex buffer uploaded
   once, index buffers patched in place), checking after every frame that
   the GPU buffers equal the client library's.
5. Writes into ``DIR``: ``frames/``, ``animation.gif``, ``contact_sheet.png``,
   ``frame.png`` (the last frame, full size), ``wireframe.png`` (the same with
   the triangles' edges: the LOD at work), ``demo.png`` (operations per
   camera-second and latency) and ``summary.json``; then stops the server.
"""

from __future__ import annotations

import argparse
import json
import os
import selectors
import signal
import subprocess
import sys
import time
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from .cli import morph_argument
from .errors import CaveclodError, FileFormatError, InputError

SERVER_START_SECONDS = 180.0     # the first start compiles the refinement kernels
OPEN_SECONDS = 600.0             # ... and its first Open waits for them (a cold numba cache: about a minute)
CAMERAS = ("A", "B", "C", "D")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="caveclod demo", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    add_arguments(ap)
    args = ap.parse_args(argv)
    try:
        return run(args)
    except CaveclodError as exc:
        print(f"caveclod: error: {exc}", file=sys.stderr)
        return 2


def add_arguments(ap: argparse.ArgumentParser) -> None:
    ap.add_argument("--out", default="out/demo", help="output directory (default out/demo)")
    ap.add_argument("--frames", type=int, default=150, help="frames to fly, at 30 per path second (default 150)")
    ap.add_argument("--size", type=int, default=256, help="cells per side of the default terrain (default 256)")
    ap.add_argument("--image", default="1280x720", help="image size, WxH (default 1280x720: four 640x360 quadrants)")
    ap.add_argument("--keep-every", type=int, default=10, metavar="N",
                    help="write every N-th frame as a PNG into frames/ (default 10; the animation has them all)")
    ap.add_argument("--wireframe", action="store_true", help="draw the triangles' edges over the terrain")
    ap.add_argument("--animation-width", type=int, default=640, metavar="PX",
                    help="largest width of the animation's frames (default 640)")
    morph_argument(ap)


def run(args) -> int:
    from .render.record import morph_ms, parse_size
    size = parse_size(args.image)
    morph_ms(args)
    if args.frames < 2:
        raise InputError(f"--frames must be at least 2, got {args.frames}")
    if args.keep_every < 1:
        raise InputError(f"--keep-every must be at least 1, got {args.keep_every}")
    if args.animation_width < 16:
        raise InputError(f"--animation-width must be at least 16 pixels, got {args.animation_width}")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    started = time.perf_counter()
    mesh_path = terrain(out / "default.cvc", args.size)
    with server(mesh_path, out / "server.log") as (port, proc):
        summary, frames = fly(f"127.0.0.1:{port}", mesh_path.stem, out, size, args)
        summary["server"] = {"pid": proc.pid, "port": port}
    summary["demo_seconds"] = round(time.perf_counter() - started, 1)
    write_outputs(out, summary, frames)
    report(out, summary)
    return 1 if summary["divergences"] else 0


def terrain(path: Path, size: int) -> Path:
    """``path``, built from the default terrain unless it already holds one of ``size``."""
    from .api import build, load
    if path.exists():
        try:
            held = load(path).summary()
            if held["faces"] == 2 * size * size and held["materials"] == 4:
                print(f"demo: reusing {path} ({held['faces']:,} triangles)", flush=True)
                return path
        except (FileFormatError, OSError):
            pass                  # another version or a damaged file: build it again
    print(f"demo: building the default terrain, {size}x{size} cells ({2 * size * size:,} triangles)", flush=True)
    mesh = build("default", size=size, progress=True)
    mesh.save(path)
    s = mesh.summary()
    print(f"demo: {path}: {s['nodes']:,} nodes, base mesh {s['base_faces']:,} faces, built in "
          f"{s['build_seconds']:.1f} s", flush=True)
    return path


@contextmanager
def server(mesh: Path, log: Path):
    """Run ``caveclod serve MESH`` on 127.0.0.1:0; yields (port, Popen); stops it by its pid on exit."""
    cmd = [sys.executable, "-m", "caveclod.cli", "serve", str(mesh), "--host", "127.0.0.1", "--port", "0",
           "--drain-seconds", "2"]
    print(f"demo: starting {' '.join(['caveclod', *cmd[3:]])}", flush=True)
    with open(log, "w") as err:
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=err, text=True)
        try:
            port = _listening_port(proc, log)
            print(f"demo: server pid {proc.pid} listening on 127.0.0.1:{port} (log: {log})", flush=True)
            yield port, proc
        finally:
            _stop(proc)


def _listening_port(proc: subprocess.Popen, log: Path) -> int:
    deadline = time.monotonic() + SERVER_START_SECONDS
    with selectors.DefaultSelector() as sel:       # not select(): no ceiling on descriptor numbers
        sel.register(proc.stdout, selectors.EVENT_READ)
        while time.monotonic() < deadline:
            if sel.select(1.0):
                line = proc.stdout.readline()
                if line.startswith("listening on "):
                    return int(line.rsplit(":", 1)[1])
                if not line and proc.poll() is not None:
                    break
    tail = log.read_text()[-800:] if log.exists() else ""
    raise CaveclodError(f"caveclod serve did not start (exit status {proc.poll()}); its log {log} ends: {tail}")


def _stop(proc: subprocess.Popen) -> None:
    """SIGTERM (the server drains and exits 0), SIGKILL after 30 s."""
    if proc.poll() is None:
        os.kill(proc.pid, signal.SIGTERM)
        try:
            proc.wait(30)
        except subprocess.TimeoutExpired:
            os.kill(proc.pid, signal.SIGKILL)
            proc.wait(30)
    print(f"demo: server stopped (exit status {proc.returncode})", flush=True)


def fly(target: str, mesh: str, out: Path, size: tuple, args) -> tuple[dict, list]:
    """The 4-camera session: record the flight into ``out/frames``; (summary, animation frames)."""
    from .client import Client, SessionEnded
    from .render.camera import quadrants
    from .render.flight import FlightError
    from .render.record import record
    qw, qh = quadrants(*size, len(CAMERAS))[0][2:]
    try:
        with Client(target, cache_dir=out / "vertex-cache") as client:
            # A server's first Open waits for its kernels: on a machine whose numba cache is
            # cold (the first demo) compiling them takes most of a minute, more than the client's
            # default of 30 s.
            print("demo: opening a session (the first run on a machine waits while the server compiles its "
                  "kernels, about a minute)", flush=True)
            with client.session(mesh, cameras=len(CAMERAS), width=qw, height=qh, timeout=OPEN_SECONDS,
                                morph_targets=args.morph_ms > 0,
                                frame_encoding="linked" if args.morph_ms > 0 else "ops") as session:
                info = session.info
                packed = info.vertex_packing if info.HasField("vertex_packing") else None
                how = "" if packed is None else (
                    f", packed into {packed.packed_bytes:,} bytes (float32: {info.vertex_format.payload_bytes:,}; "
                    f"positions within {packed.max_position_error:.2g} units)")
                print(f"demo: session of {len(CAMERAS)} cameras, {qw}x{qh} each, 1 px tolerance; "
                      f"vertex buffer {session.vertex_buffer.n_vertices:,} vertices{how}", flush=True)
                summary, frames = record(session, out / "frames", size=size, trajectory="flyover",
                                         frames=args.frames, wireframe=args.wireframe, keep_every=args.keep_every,
                                         animation=out / "animation.gif", animation_width=args.animation_width,
                                         wireframe_still=out / "wireframe.png", morph_ms=args.morph_ms,
                                         morph_speed=args.morph_speed)
    except SessionEnded as exc:
        raise CaveclodError(f"the session ended: {exc}; see the server log {out / 'server.log'}") from None
    except FlightError as exc:
        raise CaveclodError(str(exc)) from None
    summary["morph_ms"] = args.morph_ms
    summary["morph_speed"] = args.morph_speed
    summary["vertex_download"] = {
        "float32_bytes": info.vertex_format.payload_bytes,
        "packed_bytes": packed.packed_bytes if packed is not None else None,
        "max_position_error": packed.max_position_error if packed is not None else 0.0}
    summary["cameras_described"] = {
        name: f"flies a circle over the {q} quadrant of the terrain, looking ahead and down"
        for name, q in zip(CAMERAS, ("south-west", "south-east", "north-west", "north-east"))}
    return summary, frames


def write_outputs(out: Path, summary: dict, frames: list) -> None:
    """animation.gif, frame.png, contact_sheet.png, demo.png and summary.json."""
    from PIL import Image

    from .render.images import contact_sheet, save_png
    last = summary["frames_written"][-1]
    Image.open(out / "frames" / last).save(out / "frame.png")
    picks = np.linspace(0, len(frames) - 1, min(12, len(frames))).round().astype(int)
    sheet = contact_sheet([frames[i] for i in picks], columns=4,
                          labels=[f"frame {i} (t={i / 30:.1f} s)" for i in picks])
    save_png(out / "contact_sheet.png", sheet)
    try:
        plot(summary, out / "demo.png")
        summary["plot"] = "demo.png"
    except ModuleNotFoundError:
        print("demo: matplotlib is not installed (pip install 'caveclod[bench]'); no plot", file=sys.stderr)
    (out / "summary.json").write_text(json.dumps(summary, indent=1))


def plot(summary: dict, path: Path) -> None:
    """Operations per camera-second (per camera, over the flight) and pose -> frame latency."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from .client.loadtest import draw_latency_cdf
    ops = np.asarray(summary["series"]["operations"], dtype=np.float64)
    fps = summary["frames"] / summary["path_seconds"]
    t = np.arange(len(ops)) / fps
    fig, (a, b) = plt.subplots(1, 2, figsize=(10, 3.6))
    window = max(min(int(fps // 2), len(ops) - 1), 1)      # half a second, moving average
    kernel = np.ones(window) / window
    for c, name in enumerate(CAMERAS[: ops.shape[1]]):
        a.plot(t[1:], np.convolve(ops[1:, c] * fps, kernel, mode="same"), label=f"camera {name}", lw=1.2)
    a.set_yscale("symlog", linthresh=10)
    a.set_xlabel("path time (s)")
    a.set_ylabel("splits + collapses per second")
    a.set_title(f"operations per camera-second (mean {summary['operations_per_camera_second']:,.0f})", fontsize=9)
    a.legend(fontsize=8)
    a.grid(alpha=0.3)
    draw_latency_cdf(b, summary["series"]["latency_ms"])
    b.set_title(f"{summary['cameras']} cameras, {summary['mesh_faces']:,} triangles, over gRPC on loopback",
                fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def report(out: Path, s: dict) -> None:
    lat = s["latency_ms"]
    print(f"demo: {s['frames']} frames of {s['cameras']} cameras in {s['wall_seconds']} s; "
          f"{s['operations_per_camera_second']:,.0f} operations per camera-second; "
          f"{s['bytes_per_frame']['median']:,.0f} bytes per frame (median); "
          f"pose -> frame latency p50 {lat['p50']} ms, p99 {lat['p99']} ms; "
          f"{s['divergences']} divergences; GPU buffers equal to the client's after all "
          f"{s['gpu_buffers_verified_frames']} frames")
    print(f"demo: done in {s['demo_seconds']} s; output in {out}/ (frame.png, wireframe.png, animation.gif, "
          f"contact_sheet.png, demo.png, summary.json)")


if __name__ == "__main__":
    sys.exit(main())
