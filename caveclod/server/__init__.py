"""The caveclod.v1 LOD service (``caveclod serve``).

    server = LodServer(ServerConfig(meshes=["terrain.cvc"], port=0)).start()
    print(server.port)
    ...
    server.drain()                # health NOT_SERVING, sessions end after drain_seconds

Modules, one topic each: ``config`` (the options), ``meshes`` (the served
catalogue), ``session`` (one session's rules), ``registry`` (all sessions:
limits, resume, expiry), ``service`` (the thin gRPC servicer), ``auth``,
``metrics``, ``logs``, ``app`` (assembly, health, drain) and ``main`` (the
command). Needs the ``server`` extra: ``pip install 'caveclod[server]'``.
"""

from .app import LodServer
from .config import ServerConfig

__all__ = ["LodServer", "ServerConfig"]
