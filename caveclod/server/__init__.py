"""The caveclod.v1 LOD service (``caveclod serve``).

    server = LodServer(ServerConfig(meshes=["terrain.cvc"], port=0)).start()
    print(server.port)
    ...
    server.drain()                # health NOT_SERVING, sessions end after drain_seconds

Modules, one topic each: ``config`` (the options), ``meshes`` (the served
catalogue), ``session`` (one session's rules), ``registry`` (all sessions:
limits, resume, expiry), ``service`` (the thin gRPC servicer), ``auth``,
``metrics``, ``logs``, ``app`` (assembly, health, drain), ``main`` (the
command), ``probe`` (``caveclod health``) and ``warm`` (numba's cache filled
at image build). Needs the ``server`` extra: ``pip install 'caveclod[server]'``.
"""

__all__ = ["LodServer", "ServerConfig"]


def __getattr__(name: str):
    # Imported on first use: ``caveclod health`` (``.probe``), which a
    # container runs every few seconds, needs none of the server.
    if name == "LodServer":
        from .app import LodServer
        return LodServer
    if name == "ServerConfig":
        from .config import ServerConfig
        return ServerConfig
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
