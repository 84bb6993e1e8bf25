"""The ``caveclod`` command line.

    caveclod build INPUT -o OUT.cvc [--json] [--size N] [--cell-size X] ...
    caveclod build INPUT --tiles-dir DIR --tile-job I/N ...   (then: caveclod build INPUT --tiles-dir DIR -o OUT.cvc)
    caveclod inspect OUT.cvc [--json] [--verify]
    caveclod serve A.cvc [B.cvc ...] [--host H] [--port P] [--max-sessions N] ...
    caveclod loadtest --target HOST:PORT --sessions N --duration S [--json] ...
    caveclod render --target HOST:PORT --cameras N --trajectory PATH --frames K --out DIR ...
    caveclod view --target HOST:PORT [--cameras N] ...
    caveclod demo [--out DIR]
    caveclod health [--target HOST:PORT] [--service NAME]

Errors print one line on stderr and exit with status 2; never a traceback.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import sys

from .builder.memory import PEAK_BYTES_PER_TRIANGLE
from .errors import CaveclodError, InputError
from .server.config import DEFAULT_MAX_SESSIONS, default_checked_dir

DEFAULT_MORPH_MS = 500.0     # geomorph duration of render, view and demo (benchmarks/geomorph.py)

EXIT_USAGE = 2


NEGATIVE_VALUE_OPTIONS = ("--origin", "--nodata", "--z-scale", "--cell-size", "--seed", "--tile-job")
"""Options whose value may start with a minus sign that argparse takes for an option of its own."""


def _join_negative_values(argv: list[str]) -> list[str]:
    """``--origin -2700000,-4300000,3800000`` as ``--origin=-2700000,...``.

    argparse reads a value starting with ``-`` as the value only when it looks
    like one negative number (``-9999``); a point (an ECEF origin west of
    Greenwich) or an exponent (``--nodata -3.4e38``) it took for an unknown
    option and said "expected one argument".
    """
    out: list[str] = []
    for i, token in enumerate(argv):
        if (i and argv[i - 1] in NEGATIVE_VALUE_OPTIONS and out and out[-1] == argv[i - 1]
                and re.match(r"-\.?\d", token)):
            out[-1] = f"{out[-1]}={token}"
        else:
            out.append(token)
    return out


def main(argv: list[str] | None = None) -> int:
    parser = _parser()
    args = parser.parse_args(_join_negative_values(sys.argv[1:] if argv is None else list(argv)))
    try:
        code = args.run(args)
        sys.stdout.flush()           # a reader that left shows here (BrokenPipeError), not at exit
        return code
    except CaveclodError as exc:
        print(f"caveclod: error: {exc}", file=sys.stderr)
        return EXIT_USAGE
    except ModuleNotFoundError as exc:
        print(f"caveclod: error: '{args.command}' needs the Python package {exc.name!r}, which is not installed; "
              "install the extras it needs, e.g. pip install 'caveclod[all]'", file=sys.stderr)
        return EXIT_USAGE
    except MemoryError:
        print("caveclod: error: out of memory; build a smaller input or use a machine with more memory", file=sys.stderr)
        return EXIT_USAGE
    except KeyboardInterrupt:
        print("caveclod: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:
        return _stdout_closed()
    except OSError as exc:
        # What the file system refused that no check above foresaw (a name too long, a
        # directory where a file was wanted): one line naming the file, not a traceback.
        where = f"{exc.filename}: " if exc.filename else ""
        print(f"caveclod: error: {where}{exc.strerror or exc}", file=sys.stderr)
        return EXIT_USAGE


def _stdout_closed() -> int:
    """The reader of stdout left (``caveclod inspect F | head -2``): exit quietly, as
    ``cat`` does, with 128 + SIGPIPE. Python would otherwise print a traceback
    when it flushes stdout at exit: point stdout at /dev/null first."""
    import os
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        os.close(devnull)
    except (OSError, ValueError):     # no real stdout (a captured one): nothing will be flushed to a pipe
        pass
    return 141


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="caveclod", description="View-dependent continuous LOD for many cameras.")
    sub = p.add_subparsers(dest="command", required=True)

    b = sub.add_parser("build", help="build a static CAVECLOD mesh (.cvc) from a mesh, a heightfield or a built-in")
    b.add_argument("input", help="mesh file (OBJ, PLY, GLB/glTF, STL, OFF), heightfield (.npy, 16-bit .png/.tif, "
                                 "SRTM .hgt, ESRI .asc; its first row is the north) or a "
                                 "built-in: 'default' (smooth terrain), 'rough' (rough terrain with no-data holes), "
                                 "'scan' (a range scan), 'debris' (20 x --size small parts)")
    b.add_argument("-o", "--output", help="the .cvc file to write (required but with --tile-job)")
    b.add_argument("--json", action="store_true", help="print the build report as one JSON object on stdout")
    b.add_argument("--size", type=int, default=256, help="cells per side of a built-in (default 256: 131,072 "
                                                         "triangles of the default terrain)")
    b.add_argument("--seed", type=int, help="seed of a built-in")
    b.add_argument("--cell-size", type=float, help="heightfield grid spacing (default: what a GeoTIFF's or an SRTM "
                                                   ".hgt tile's or an .asc grid's georeference states, in metres for "
                                                   "degrees; else 1)")
    b.add_argument("--z-scale", type=float, default=1.0, help="heightfield height scale")
    b.add_argument("--materials", help="heightfield material map (.npy, one integer class per cell)")
    b.add_argument("--stride", default="1", metavar="K",
                   help="build a heightfield from every Kth sample a side: cells K times as wide, about K*K times "
                        "fewer triangles, the south-west sample kept (default 1: every sample); for rasters too "
                        "large to build here, which the memory check names the K for")
    b.add_argument("--nodata", type=float, help="heightfield value marking missing samples, which become holes "
                                                "(NaN, a GeoTIFF's GDAL_NODATA and -32768 in 16-bit signed grids always do)")
    b.add_argument("--crease-angle", type=float, help="degrees; edges sharper than this become normal seams where the "
                                                     "input has no normals (default: 30 for meshes, smooth normals "
                                                     "for heightfields)")
    b.add_argument("--origin", metavar="auto|X,Y,Z", help="subtract this point from every position (auto: the "
                                                        "mesh's centre, rounded), recorded in the file; for meshes "
                                                        "in world coordinates far from 0, where the float32 "
                                                        "positions of the .cvc would lose their detail")
    b.add_argument("--weld", type=float, help="merge positions closer than about this distance "
                                              "(default: only bitwise-equal positions are one)")
    b.add_argument("--tiles", type=int, help="tiles per side, a power of two: tiles are simplified in parallel with "
                                             "their borders fixed, then merged 2 x 2 (default: by size, about "
                                             "65,536-131,072 faces a tile; 1: no tiles)")
    b.add_argument("--workers", type=int, help="threads of the build (default: the cores, at most 8); the file is the "
                                               "same whatever their number")
    b.add_argument("--tiles-dir", help="directory of blocks of tiles shared by separate build jobs: with "
                                       "--tile-job, this job's blocks are written there; without, the blocks there "
                                       "are read and merged (the mesh is the same as a build in one process)")
    b.add_argument("--tile-job", metavar="I/N", help="be job I of N tile jobs (e.g. a Kubernetes Indexed Job's "
                                                     "completion index): make blocks of tiles I, I+N, ... into "
                                                     "--tiles-dir and stop; then run the build with --tiles-dir and "
                                                     "-o to merge them")
    b.add_argument("--no-memory-check", action="store_true",
                   help="build even if the input looks too large for the memory available (by default such a build "
                        f"is refused before it starts: it needs about {PEAK_BYTES_PER_TRIANGLE} bytes per input "
                        "triangle)")
    b.add_argument("--quiet", action="store_true", help="no progress on stderr")
    b.set_defaults(run=_build)

    i = sub.add_parser("inspect", help="print the counts of a .cvc file")
    i.add_argument("path")
    i.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    i.add_argument("--verify", action="store_true", help="re-hash the whole file and check it is intact")
    i.set_defaults(run=_inspect)

    k = sub.add_parser("pack", help="store the packed vertex downloads and the derived arrays (each vertex's "
                                    "position, faces per material, connected parts) in a .cvc built before "
                                    "caveclod stored them (a server then need not make them at start)")
    k.add_argument("path")
    k.add_argument("-o", "--output", help="write here instead of rewriting PATH")
    k.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    k.add_argument("--quiet", action="store_true", help="no progress bar")
    k.set_defaults(run=_pack)

    s = sub.add_parser("serve", help="serve .cvc meshes to thin clients over gRPC (caveclod.v1)",
                       description="Serve static meshes over gRPC. Each mesh is served under its file stem. "
                                   "SIGTERM or SIGINT drains: health goes NOT_SERVING, new sessions are refused, "
                                   "open ones end after --drain-seconds, and the process exits 0.")
    s.add_argument("meshes", nargs="+", metavar="MESH.cvc", help=".cvc files built with 'caveclod build'")
    s.add_argument("--host", default="0.0.0.0", help="address to listen on (default 0.0.0.0: every interface)")
    s.add_argument("--port", type=int, default=50051, help="port (default 50051; 0 picks a free port)")
    s.add_argument("--max-sessions", type=int, default=DEFAULT_MAX_SESSIONS,
                   help=f"sessions held at once, resumable ones included (default {DEFAULT_MAX_SESSIONS}: what one "
                        "server process held at 30 Hz with p99 < 50 ms on a 1M-triangle terrain; see the README)")
    s.add_argument("--max-cameras", type=int, default=4, help="cameras per session (default 4)")
    s.add_argument("--ack-window", type=int, default=4,
                   help="frames in flight before an ack, for clients that ask for none (default 4; "
                        "requests are clamped to 1..32)")
    s.add_argument("--resume-ttl", type=int, default=30, metavar="SECONDS",
                   help="seconds a session whose stream broke stays resumable (default 30)")
    s.add_argument("--drain-seconds", type=float, default=20.0, metavar="SECONDS",
                   help="grace period of open sessions on SIGTERM/SIGINT (default 20)")
    s.add_argument("--max-faces", type=int, default=None,
                   help="cap on active faces per camera (default: none; a camera's memory is bounded by the "
                        "mesh's size anyway)")
    s.add_argument("--max-ops", type=int, default=None,
                   help="cap on split+collapse operations per camera update (default: none)")
    s.add_argument("--metrics-port", type=int, default=None, metavar="P",
                   help="serve Prometheus metrics on http://METRICS-HOST:P/metrics (default: off)")
    s.add_argument("--metrics-host", default="0.0.0.0", help="address of the metrics exporter (default 0.0.0.0)")
    s.add_argument("--web-port", type=int, default=None, metavar="P",
                   help="also serve the browser viewer at http://WEB-HOST:P/ and sessions over WebSocket at "
                        "/v1/session (default: off; 0 picks a free port)")
    s.add_argument("--web-host", default=None,
                   help="address of the viewer (default: --host)")
    s.add_argument("--token-file", metavar="F",
                   help="require 'authorization: Bearer <token>' with a token from F (one per line)")
    s.add_argument("--tls-cert", metavar="F", help="PEM certificate chain; with --tls-key, serve TLS only")
    s.add_argument("--tls-key", metavar="F", help="PEM private key of --tls-cert")
    s.add_argument("--log-format", choices=("text", "json"), default="text",
                   help="one line per session event on stderr, as text or JSON (default text)")
    s.add_argument("--processes", type=int, default=1, metavar="N",
                   help="N server processes on the one port (SO_REUSEPORT), each with its own event loop, under a "
                        "supervisor that drains them together and sums their metrics (default 1); --max-sessions "
                        "is per process")
    s.add_argument("--transport", choices=("grpc", "h2"), default="grpc",
                   help="grpc: grpc.aio (the default; TLS, every gRPC feature); h2: caveclod's own HTTP/2 on the "
                        "same event loop, the same services (Lod, health, reflection) at less CPU a frame, "
                        "plaintext only (docs/server.md, \"Server model\")")
    s.add_argument("--checked-dir", default=default_checked_dir(), metavar="DIR",
                   help="where meshes that passed the structural check at start are remembered, so that a start "
                        "on an unchanged file (the same inode, size, mtime and ctime) skips reading it again "
                        "(about 2 s at 33.5M triangles); default $CAVECLOD_CHECKED_DIR, else "
                        "$XDG_CACHE_HOME/caveclod/checked; 'none': check at every start")
    s.add_argument("--reuse-port", action="store_true", help=argparse.SUPPRESS)      # a process of --processes
    s.add_argument("--announce-metrics", action="store_true", help=argparse.SUPPRESS)  # its metrics port on stdout
    s.set_defaults(run=_serve)

    h = sub.add_parser("health", help="ask a server's gRPC health service whether it serves (exit 0) or not (1)",
                       description="Ask the grpc.health.v1 service of a caveclod server (or a balancer in front of "
                                   "it) for a service's status. Exits 0 when SERVING, 1 otherwise (NOT_SERVING while "
                                   "draining, no answer, no connection), with the reason on stderr. Containers run "
                                   "it as their HEALTHCHECK.")
    h.add_argument("--target", default="127.0.0.1:50051", metavar="HOST:PORT",
                   help="the server (default 127.0.0.1:50051, the default port of caveclod serve)")
    h.add_argument("--service", default="caveclod.v1.Lod",
                   help="service name to ask about: 'caveclod.v1.Lod' (default) or '' for the server as a whole")
    h.add_argument("--timeout", type=float, default=2.0, metavar="S", help="seconds to wait for the answer (default 2)")
    h.add_argument("--tls-ca", metavar="F", help="PEM CA certificate: connect with TLS and trust it")
    h.set_defaults(run=_health)

    t = sub.add_parser("loadtest", help="measure a server: many windowless sessions flying camera paths",
                       description="Open --sessions sessions of --cameras cameras each, send poses at --rate Hz "
                                   "along --trajectory for --duration seconds, verify every checksum, and report "
                                   "pose->frame latency, frames/s and bytes. Exits 1 on any divergence or error.")
    t.add_argument("--target", required=True, metavar="HOST:PORT", help="the server")
    t.add_argument("--mesh", help="mesh name (default: the first ListMeshes reports)")
    t.add_argument("--sessions", type=int, default=1, help="concurrent sessions (default 1)")
    t.add_argument("--cameras", type=int, default=1, help="cameras per session (default 1)")
    t.add_argument("--duration", type=float, default=10.0, metavar="S", help="seconds of poses (default 10)")
    t.add_argument("--warmup", type=float, default=1.0, metavar="S",
                   help="seconds at the start whose poses are not timed (cameras refine up from the base mesh; "
                        "default 1)")
    t.add_argument("--rate", type=float, default=30.0, metavar="HZ", help="poses per second per camera (default 30)")
    t.add_argument("--trajectory", choices=("flyover", "circle", "rotate", "line"), default="flyover",
                   help="camera path (caveclod.paths; default flyover)")
    t.add_argument("--tolerance", type=float, default=1.0, metavar="PX", help="screen-space error (default 1 px)")
    t.add_argument("--width", type=int, default=1280, help="viewport width (default 1280)")
    t.add_argument("--height", type=int, default=720, help="viewport height (default 720)")
    t.add_argument("--fov", type=float, default=60.0, help="vertical field of view, degrees (default 60)")
    refine_arguments(t)
    t.add_argument("--token", help="bearer token (or set CAVECLOD_TOKEN)")
    t.add_argument("--tls-ca", metavar="F", help="PEM CA certificate: connect with TLS and trust it")
    t.add_argument("--cache-dir", help="vertex buffer cache (default $XDG_CACHE_HOME/caveclod/vertex-buffers)")
    _cache_arguments(t, "; the JSON adds vertices_inserted, vertex_bytes_per_frame and cache_hit_rate")
    t.add_argument("--processes", type=int, default=1, metavar="N",
                   help="spread the sessions over N processes (one event loop each; default 1): one Python process "
                        "drives about a core's worth of sessions")
    t.add_argument("--connections", type=int, metavar="N",
                   help="gRPC connections the sessions share (default: one per session, as viewers have; a "
                        "server's --processes spreads connections, not streams)")
    t.add_argument("--transport", choices=("auto", "h2", "grpc"), default="auto",
                   help="h2: the sessions' streams over HTTP/2 framed by caveclod itself (HPACK from the loadtest "
                        "extra), about half of grpc.aio's CPU per frame, plaintext only; grpc: grpc.aio; auto (the "
                        "default): h2 where hpack is installed and no --tls-ca is given, else grpc")
    t.add_argument("--shard", help=argparse.SUPPRESS)        # I/N: the sessions of one of N processes
    t.add_argument("--start-at", type=float, help=argparse.SUPPRESS)   # their shared start (time.perf_counter)
    t.add_argument("--frame-encoding", choices=("linked", "ops", "raw"), default="linked",
                   help="how index-buffer writes travel: linked (op streams that also name vertices by their morph "
                        "targets, which the sessions then download: the default), ops (op streams), or raw "
                        "(uint32 arrays, what caveclod.v1 clients before op streams read)")
    t.add_argument("--decoder", choices=("auto", "compiled", "numpy"), default="auto",
                   help="how op streams are decoded: compiled (a numba kernel, about a seventh of numpy's CPU; "
                        "needs caveclod[build]), numpy (what thin clients run); auto (the default): compiled where "
                        "numba is installed")
    t.add_argument("--json", action="store_true", help="print one JSON object with the figures on stdout")
    t.add_argument("--samples", action="store_true", help="with --json: add every latency sample (ms) as latencies_ms")
    t.add_argument("--plot", metavar="FILE", help="write a pose->frame latency plot (PNG; needs matplotlib)")
    t.set_defaults(run=_loadtest)

    r = sub.add_parser("render", help="fly cameras through a server and write the frames as PNG and an animation",
                       description="Open one session of --cameras cameras, fly them along --trajectory for --frames "
                                   "frames (30 per path second), render each frame on the GPU (offscreen, EGL) as "
                                   "quadrants of one image, and write DIR/frame_NNNN.png, DIR/animation.gif and "
                                   "DIR/render.json. Exits 1 on divergences.")
    _client_arguments(r)
    r.add_argument("--cameras", type=int, default=4, help="cameras, drawn as quadrants of one image (1-4; default 4)")
    r.add_argument("--trajectory", choices=("flyover", "circle", "rotate", "line"), default="flyover",
                   help="camera path (caveclod.paths; default flyover)")
    r.add_argument("--frames", type=int, default=90, help="frames to render (default 90)")
    r.add_argument("--fps", type=float, default=30.0, help="frames per path second (default 30)")
    r.add_argument("--size", default="1280x720", help="image size WxH (default 1280x720)")
    r.add_argument("--wireframe", action="store_true", help="overlay the triangles' edges")
    r.add_argument("--out", required=True, metavar="DIR", help="directory for the frames")
    _cache_arguments(r)
    morph_argument(r)
    r.set_defaults(run=_render)

    v = sub.add_parser("view", help="an interactive window flying one camera through a server (needs a display)",
                       description="Fly camera 1 with the mouse and keys; cameras 2-4 (--cameras) fly the flyover "
                                   "path beside it, as quadrants. Keys: W/S forward/back, A/D sideways, Q/E down/up, "
                                   "drag the mouse to look, scroll for speed, F wireframe, Esc quit.")
    _client_arguments(v)
    v.add_argument("--cameras", type=int, default=1, help="cameras, drawn as quadrants (1-4; default 1)")
    v.add_argument("--size", default="1280x720", help="window size WxH (default 1280x720)")
    v.add_argument("--wireframe", action="store_true", help="start with the wireframe overlay on")
    v.add_argument("--frames", type=int, default=None, help="quit after this many drawn frames (default: run until closed)")
    v.add_argument("--screenshot", metavar="FILE", help="write the last drawn frame as PNG on exit")
    _cache_arguments(v)
    morph_argument(v)
    v.set_defaults(run=_view)

    d = sub.add_parser("demo", help="build the default terrain, serve it, fly 4 cameras through the service and "
                                    "render them (the README's first command)")
    from .demo import add_arguments
    add_arguments(d)
    d.set_defaults(run=_demo)
    return p


def _client_arguments(p: argparse.ArgumentParser) -> None:
    """Options of the commands that open a session as a client."""
    p.add_argument("--target", required=True, metavar="HOST:PORT", help="the server")
    p.add_argument("--mesh", help="mesh name (default: the first ListMeshes reports)")
    p.add_argument("--tolerance", type=float, default=None, metavar="PX",
                   help="screen-space error in pixels (default: the server's, 1 px)")
    p.add_argument("--fov", type=float, default=60.0, help="vertical field of view, degrees (default 60)")
    refine_arguments(p)
    p.add_argument("--token", help="bearer token (or set CAVECLOD_TOKEN)")
    p.add_argument("--tls-ca", metavar="F", help="PEM CA certificate: connect with TLS and trust it")
    p.add_argument("--cache-dir", help="vertex buffer cache (default $XDG_CACHE_HOME/caveclod/vertex-buffers)")


def refine_arguments(p: argparse.ArgumentParser) -> None:
    """``--no-prune`` and ``--strict-bound`` of the commands that open sessions (render, view, loadtest)."""
    p.add_argument("--no-prune", action="store_true",
                   help="draw every part of the mesh, however small or far out of view (by default the server "
                        "hides a connected part while it is smaller than the tolerance or outside the view)")
    p.add_argument("--strict-bound", action="store_true",
                   help="the strict error bound: every original position in view within the tolerance of what "
                        "is drawn, for more faces (RefineOptions.strict_bound)")


def morph_argument(p: argparse.ArgumentParser) -> None:
    """``--morph-ms`` of the commands that draw (render, view, demo); checked by
    :func:`caveclod.render.record.morph_ms`."""
    p.add_argument("--morph-ms", type=float, default=DEFAULT_MORPH_MS, metavar="MS",
                   help=f"geomorphs: a vertex a split brings in grows out of the surface over MS milliseconds "
                        f"instead of popping in (default {DEFAULT_MORPH_MS:g}; 0: off). Needs the packed "
                        "vertex download")
    p.add_argument("--morph-speed", type=float, metavar="PX_PER_S",
                   help="geomorphs move at this many pixels a second on screen: each morph lasts its path "
                        "over it, at most --morph-ms (give a long one, e.g. 8000); at 5, 99 %% of a flight's "
                        "frames jumped less than a quarter pixel at a 4 px tolerance (README, Rendering)")


def _cache_arguments(p: argparse.ArgumentParser, more: str = "") -> None:
    """How vertices reach the commands that open sessions: packed or float32, or cache mode's slots."""
    p.add_argument("--vertex-encoding", choices=("packed", "float32"), default="packed",
                   help="how the vertex buffer downloads: packed (quantized and deflated, 1-7 bytes a vertex; "
                        "the default) or float32 (32 bytes a vertex, exact)")
    p.add_argument("--position-bits", type=int, metavar="B",
                   help="packed: bits per position component, 8-24 (default 20; a position moves by about "
                        "extent * 2^-B at most)")
    p.add_argument("--cache-vertices", type=int, metavar="N",
                   help="cache mode: N vertex slots per camera instead of the whole vertex buffer" + more)
    p.add_argument("--cache-strategy", choices=("fa", "lru", "lru_pq"),
                   help="cache mode: which slot a new vertex overwrites (default lru)")
    p.add_argument("--cache-pq-fraction", type=float, metavar="F",
                   help="cache mode with lru_pq: share of the slots in the error priority queue (default 0.1)")


def _render(args) -> int:
    from .render.record import main as render
    return render(args)


def _view(args) -> int:
    from .render.window import main as view
    return view(args)


def _demo(args) -> int:
    from .demo import run
    return run(args)


def _serve(args) -> int:
    from .server.main import serve
    return serve(args)


def _health(args) -> int:
    from .server.probe import main as health
    return health(args)


def _loadtest(args) -> int:
    from .client.loadtest import main as loadtest
    return loadtest(args)


def _build(args) -> int:
    from .api import build, build_tiles
    options = dict(cell_size=args.cell_size, z_scale=args.z_scale, materials=args.materials,
                   crease_angle=args.crease_angle, size=args.size, seed=args.seed, nodata=args.nodata, weld=args.weld,
                   origin=args.origin, stride=_whole_number("--stride", args.stride),
                   progress=not args.quiet, tiles=args.tiles, workers=args.workers,
                   check_memory=not args.no_memory_check)
    if args.tile_job is not None:
        if args.tiles_dir is None or args.output is not None:
            raise InputError("--tile-job writes tiles, not a .cvc: give it --tiles-dir and no -o (the merge, "
                             "'caveclod build INPUT --tiles-dir DIR -o OUT.cvc', writes the file)")
        _print(build_tiles(args.input, args.tiles_dir, args.tile_job, **options), args.json)
        return 0
    if args.output is None:
        raise InputError("-o/--output is required: the .cvc file to write")
    _check_output(args.output, args.input)       # before the build, not after minutes of it
    mesh = build(args.input, tiles_dir=args.tiles_dir, **options)
    _save(mesh, args.output)
    _remember_checked(args.output)
    report = mesh.summary()
    report["output"] = args.output
    _print(report, args.json)
    return 0


def _check_output(output: str, source: str | None = None) -> None:
    """Refuse in one line, before any work, an output the build could not write or must not: no
    file name, not a regular file, a directory that is missing or not writable, or the input
    itself (``build m.obj -o m.obj`` replaced the mesh with the .cvc)."""
    from .staticmesh import refuse_output_path
    refuse_output_path(output)
    parent = os.path.dirname(os.path.abspath(output))
    if not os.access(parent, os.W_OK | os.X_OK):
        raise InputError(f"cannot write {output}: its directory {parent} is not writable")
    if source is not None and os.path.exists(output) and os.path.exists(source) \
            and os.path.samefile(output, source):
        raise InputError(f"the output {output} is the input: writing it would replace the mesh; give another -o")


def _whole_number(option: str, text: str) -> int:
    """``text`` as an int, refused in one line (argparse's own refusal prints its usage too)."""
    try:
        return int(text)
    except ValueError:
        raise InputError(f"{option} must be a whole number, got {text!r}") from None


def _pack(args) -> int:
    from .staticmesh import load
    from .vertexpack import attach_packed
    output = args.path if args.output is None else args.output     # -o '' names no file: refused, not in place
    _check_output(output)
    mesh = load(args.path)       # checked, as serve would
    mesh.store_derived()
    attach_packed(mesh, progress=not args.quiet)
    _save(mesh, output)          # a new file renamed into place: the mapped one stays readable meanwhile
    _remember_checked(output)
    _print({"path": str(output), "attachments": mesh.summary()["attachments"], "derived_bytes": mesh.derived_bytes},
           args.json)
    return 0


def _remember_checked(path) -> None:
    """Run on the file just written the structural check ``caveclod serve`` runs at a file's first
    start, and remember that it passed where serve looks by default (``--checked-dir``), so that
    serving it here starts as a restart does (a 47M-triangle terrain: 4.1 -> 0.43 s to SERVING).
    A directory that cannot be written only costs that; ``CAVECLOD_CHECKED_DIR=none`` skips it."""
    from .meshcheck import check_mesh
    from .staticmesh import load
    checked_dir = default_checked_dir()
    if checked_dir != "none":
        check_mesh(load(path, check=False), checked_dir=checked_dir)


def _save(mesh, path) -> None:
    """``mesh.save(path)``, an OSError said as what to do."""
    try:
        mesh.save(path)
    except OSError as exc:
        raise CaveclodError(f"cannot write {path}: {exc.strerror}; check the directory exists, is writable and has "
                            "room for the file") from None


def _inspect(args) -> int:
    from .staticmesh import load
    mesh = load(args.path)       # parses the header defensively and checks the structure (caveclod.meshcheck)
    if args.verify:
        mesh.verify()            # and re-hashes every array
    report = mesh.summary()
    report["classes"] = mesh.class_tally()
    report["path"] = args.path
    _print(report, args.json)
    return 0


def _print(report: dict, as_json: bool) -> None:
    if as_json:
        print(json.dumps(report))
        return
    width = max(len(k) for k in report)
    for key, value in report.items():
        print(f"{key:<{width}}  {value}")


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
