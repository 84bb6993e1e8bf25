"""What ``caveclod serve`` can be told, with defaults meant for a public deployment.

Each default is argued in the README's "Serving" section; the capacity
figures behind ``max_sessions`` come from ``benchmarks/service.py``.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field

MAX_ACK_WINDOW = 32          # a client may ask for up to this many frames in flight
# Measured (README, "Service figures"; benchmarks/service.py): one server
# process and the load generator sharing 2 cores held 32 one-camera sessions
# at 30 Hz on the 1M-triangle terrain with p99 pose -> frame of 6 to 16 ms,
# and stayed under 50 ms up to 48 in every run (up to 80 in some); 32 leaves
# room for keyframes, far camera jumps and a busier node. The deploy files
# use the same limit; past it, a replica refuses with RESOURCE_EXHAUSTED and
# the balancer's next replica takes the session.
DEFAULT_MAX_SESSIONS = 32


# TLS is grpc.aio's: caveclod's own HTTP/2 (transport "h2") serves plaintext.
H2_PLAINTEXT_ONLY = "--transport h2 serves plaintext only; serve TLS with the default --transport grpc"


def default_checked_dir() -> str:
    """Where ``caveclod serve`` remembers checked meshes: $CAVECLOD_CHECKED_DIR, else
    ``$XDG_CACHE_HOME/caveclod/checked`` (``~/.cache/caveclod/checked`` where XDG_CACHE_HOME is unset)."""
    if os.environ.get("CAVECLOD_CHECKED_DIR"):
        return os.environ["CAVECLOD_CHECKED_DIR"]
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return os.path.join(base, "caveclod", "checked")


@dataclass
class ServerConfig:
    """Options of a LOD server (the ``caveclod serve`` flags, same names).

    Attributes:
        meshes: paths of the ``.cvc`` files to serve, each under its stem.
        host, port: where to listen; port 0 picks a free port.
        max_sessions: sessions held at once, resumable ones included; the
            next Open gets RESOURCE_EXHAUSTED. Default: the capacity
            measured at 30 Hz on a 1M-triangle terrain.
        max_cameras: cameras per session.
        ack_window: frames in flight before an ack when the client asks for
            none; a client's own request is clamped to 1..MAX_ACK_WINDOW.
        resume_ttl: seconds a session whose stream broke stays resumable.
        drain_seconds: grace period of open sessions after SIGTERM/SIGINT.
        max_faces: cap on active faces per camera (a client's max_faces is
            clamped to it), or None. A camera's memory is bounded by the
            mesh anyway (at most Equation 1's 4n + 4p + 12 n + 36 p).
        max_ops: cap on operations per camera update, or None (unlimited).
        metrics_port: Prometheus exporter port, or None for none.
        metrics_host: address the exporter listens on.
        tokens: accepted bearer tokens; empty: no authentication.
        tls_cert, tls_key: PEM certificate chain and private key (bytes),
            or None for a plaintext port.
        keepalive_seconds: the server pings a connection idle this long ...
        keepalive_timeout: ... and drops it when no answer comes in this long.
        settle_seconds: pause before a convergence update (see the proto's
            Lod.Session comment): a camera still moving sends a new pose first.
        reuse_port: share the port with other processes (SO_REUSEPORT; the
            processes of ``caveclod serve --processes N``).
        web_port: serve the browser viewer and WebSocket sessions on this
            HTTP port (:mod:`.web`), or None for none; 0 picks a free port.
        web_host: address the viewer listens on; None: ``host``.
        transport: "grpc" (grpc.aio) or "h2" (:mod:`.h2server`: caveclod's own
            HTTP/2, plaintext only).
        checked_dir: where meshes that passed the structural check are
            remembered (:class:`caveclod.meshcheck.CheckedStamp`), so that a
            start on an unchanged file skips it; None: check at every start.
    """

    meshes: list = field(default_factory=list)
    host: str = "0.0.0.0"
    port: int = 50051
    max_sessions: int = DEFAULT_MAX_SESSIONS
    max_cameras: int = 4
    ack_window: int = 4
    resume_ttl: int = 30
    drain_seconds: float = 20.0
    max_faces: int | None = None
    max_ops: int | None = None
    metrics_port: int | None = None
    metrics_host: str = "0.0.0.0"
    tokens: tuple = ()
    tls_cert: bytes | None = None
    tls_key: bytes | None = None
    keepalive_seconds: float = 20.0
    keepalive_timeout: float = 10.0
    settle_seconds: float = 0.05
    reuse_port: bool = False
    web_port: int | None = None
    web_host: str | None = None
    transport: str = "grpc"
    checked_dir: str | None = None
