"""The thin caveclod.v1 client: numpy, grpcio and protobuf, nothing else.

Blocking::

    from caveclod.client import Client
    with Client("localhost:50051") as client:
        with client.session("terrain", cameras=1, width=1280, height=720) as s:
            s.send_pose(0, eye=(5000, -2000, 1500), target=(5000, 5000, 300), up=(0, 0, 1))
            frame = s.next_frame(timeout=1.0)
            positions = s.vertex_buffer.positions      # (d, 3) float32
            tris = s.buffer(0, 2)                      # (count, 3) uint32 of camera 0, material 2

asyncio: :mod:`caveclod.client.aio` (``AsyncClient``, same methods, awaited).

What the client does for you, as the proto asks: downloads the vertex
buffer once and caches it on disk by ``vertex_buffer_hash``
(:mod:`.cache`); applies each frame, part by part, to per-(camera,
material) index buffers (:mod:`.buffers`); checks every CRC-32, acks, and
asks for a keyframe on a mismatch or a bad frame; resumes a broken stream
with its session token, backing off (:mod:`.session`). In cache mode
(``cache_vertices=N``) it holds N vertex slots per camera instead of the
vertex buffer (:mod:`.slots`), written by the frames. The rules live once,
without I/O, in :mod:`.protocol`; the load tester is :mod:`.loadtest`.

This package must not import the server, the core's build or refinement
modules, numba or trimesh: ``pip install caveclod`` (the ``client`` extra)
installs only numpy, grpcio and protobuf. ``tests/test_client_imports.py``
checks it.
"""

from .buffers import IndexBuffers
from .cache import VertexBufferCache
from .protocol import CameraUpdate, FrameUpdate, ProtocolError, SessionProtocol, VertexBuffer
from .session import Client, Session, SessionEnded
from .slots import SlotBuffer

__all__ = ["Client", "Session", "SessionEnded", "FrameUpdate", "CameraUpdate", "VertexBuffer", "IndexBuffers",
           "VertexBufferCache", "SessionProtocol", "ProtocolError", "SlotBuffer"]
