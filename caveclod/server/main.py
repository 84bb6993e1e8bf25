"""``caveclod serve``: run a LOD server until SIGTERM or SIGINT, then drain and exit 0.

The first line on stdout is ``listening on HOST:PORT`` (flushed), printed
once the server accepts sessions; logs go to stderr.
"""

from __future__ import annotations

import math

import gc
import signal
import threading
from pathlib import Path

from ..errors import InputError
from . import logs
from .auth import read_tokens
from .config import H2_PLAINTEXT_ONLY, ServerConfig


MAX_PROCESSES = 256
"""Most --processes: one a core is the point (README, "Scaling out"); 256 covers the largest machines."""


def config_from_args(args) -> ServerConfig:
    """A ServerConfig from the parsed ``caveclod serve`` arguments; InputError for bad ones."""
    if (args.tls_cert is None) != (args.tls_key is None):
        raise InputError("--tls-cert and --tls-key go together; give both (PEM files) or neither")
    for name in ("max_sessions", "max_cameras", "ack_window", "max_faces", "max_ops"):
        if getattr(args, name) is not None and getattr(args, name) < 1:
            raise InputError(f"--{name.replace('_', '-')} must be at least 1, got {getattr(args, name)}")
    for flag, port in (("--port", args.port), ("--web-port", args.web_port), ("--metrics-port", args.metrics_port)):
        # Out of range, grpc.aio took --port -1 as 65535 and 65536 as a free port; the exporter raised.
        if port is not None and not 0 <= port <= 65535:
            raise InputError(f"{flag} must be a port number (0 to 65535; 0 picks a free one), got {port}")
    if args.web_port == 0 and args.processes > 1:
        raise InputError("--processes N shares one --web-port between its processes: give a port number, not 0")
    if getattr(args, "transport", "grpc") == "h2" and args.tls_cert is not None:
        raise InputError(H2_PLAINTEXT_ONLY)
    if not (0 <= args.resume_ttl < math.inf and 0 <= args.drain_seconds < math.inf):
        # NaN ended a drain at once, inf never let the server exit after SIGTERM.
        raise InputError(f"--resume-ttl and --drain-seconds must be finite numbers >= 0, got {args.resume_ttl} and "
                         f"{args.drain_seconds}")
    tls = [_read(p, flag) for p, flag in ((args.tls_cert, "--tls-cert"), (args.tls_key, "--tls-key"))]
    return ServerConfig(
        meshes=list(args.meshes), host=args.host, port=args.port, max_sessions=args.max_sessions,
        max_cameras=args.max_cameras, ack_window=args.ack_window, resume_ttl=args.resume_ttl,
        drain_seconds=args.drain_seconds, max_faces=args.max_faces, max_ops=args.max_ops,
        metrics_port=args.metrics_port, metrics_host=args.metrics_host,
        tokens=read_tokens(args.token_file) if args.token_file else (), tls_cert=tls[0], tls_key=tls[1],
        reuse_port=args.reuse_port, web_port=args.web_port, transport=getattr(args, "transport", "grpc"),
        web_host=args.web_host, checked_dir=None if args.checked_dir == "none" else args.checked_dir)


def _read(path, flag: str) -> bytes | None:
    if path is None:
        return None
    try:
        return Path(path).read_bytes()
    except OSError as exc:
        raise InputError(f"cannot read {flag} {path}: {exc.strerror}") from None


def serve(args) -> int:
    """Run the server of ``args`` (see ``caveclod serve --help``); returns the exit status."""
    from .app import LodServer
    if not 1 <= args.processes <= MAX_PROCESSES:
        # Each process loads the meshes and the kernels; a thousand took longer to start than a
        # SIGTERM waited for (it waits for every process to have started).
        raise InputError(f"--processes must be from 1 to {MAX_PROCESSES}, got {args.processes}")
    config = config_from_args(args)
    if args.processes > 1:
        from .processes import supervise
        return supervise(args)
    logs.configure(args.log_format)
    # Handlers first: a signal that arrives while the server starts (or just
    # after the listening line, which is when a supervisor may send one)
    # must drain it, not interrupt Python.
    stop = threading.Event()
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, lambda signum, frame: stop.set())
    server = LodServer(config).start()
    print(f"listening on {config.host}:{server.port}", flush=True)
    if server.web_port is not None:
        print(f"viewer on http://{config.web_host or config.host}:{server.web_port}/", flush=True)
    if server.metrics_port is not None:
        logs.event("server.metrics", port=server.metrics_port)
        if args.announce_metrics:         # a --processes supervisor reads it here
            print(f"metrics on {server.metrics_port}", flush=True)
    frozen = False
    while not stop.wait(0.2):        # a timed wait lets the signal handler run
        if not frozen and server.sessions.ready.is_set():
            # Everything loaded by now (numba's and grpc's modules, the
            # meshes) lives as long as the process: move it out of the
            # collector's reach. A full collection over it paused every
            # session for up to 73 ms under load, which alone set the p99.
            gc.collect()
            gc.freeze()
            frozen = True
    logs.event("server.signal")
    server.drain()
    return 0
