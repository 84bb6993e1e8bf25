"""Compile and cache every numba kernel a server runs: ``python -m caveclod.server.warm MESH.cvc``.

Container images run it at build time (deploy/Dockerfile), so that numba's
cache (``NUMBA_CACHE_DIR``) holds the kernels and a new container serves
within seconds instead of compiling on its first session. It starts a real
server on loopback, opens one session through the client library, flies
its camera for a few frames (refinement, deltas, keyframes and their
encoding all run), closes it and stops the server.
"""

from __future__ import annotations

import sys


def warm(mesh_path: str, frames: int = 8) -> int:
    """Serve ``mesh_path`` on 127.0.0.1:0 and run one session of ``frames`` poses; returns frames received."""
    from ..client import Client
    from .app import LodServer
    from .config import ServerConfig
    server = LodServer(ServerConfig(meshes=[mesh_path], host="127.0.0.1", port=0)).start()
    try:
        if not server.sessions.ready.wait(600):
            raise RuntimeError("the refinement kernels did not load in 10 minutes")
        received = 0
        with Client(f"127.0.0.1:{server.port}", cache_dir=False) as client:
            with client.session(server.catalogue.names()[0], width=320, height=180) as s:
                lo, hi = s.vertex_buffer.positions.min(0), s.vertex_buffer.positions.max(0)
                for i in range(frames):
                    t = i / max(frames - 1, 1)
                    eye = (lo[0] + t * (hi[0] - lo[0]), lo[1] - 1.0, hi[2] + 1.0 + (hi[0] - lo[0]) * (1 - t))
                    s.send_pose(0, eye, tuple((lo + hi) / 2))
                    received += s.next_frame(timeout=60) is not None
                s.request_keyframe(0)
                received += s.next_frame(timeout=60) is not None
        return received
    finally:
        server.stop(grace=0)


if __name__ == "__main__":  # pragma: no cover - run by the Dockerfile
    if len(sys.argv) != 2:
        sys.exit("usage: python -m caveclod.server.warm MESH.cvc")
    print(f"warm: {warm(sys.argv[1])} frames", file=sys.stderr)
