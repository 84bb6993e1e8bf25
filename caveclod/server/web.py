"""The browser's way in (``caveclod serve --web-port P``): the viewer page, and
caveclod.v1 sessions over WebSocket on the server's own event loop.

A browser cannot speak bidirectional gRPC, so the same ClientMessage and
ServerMessage bytes travel one per binary WebSocket message (the proto's
"WebSocket" section). :class:`WebSocketCall` gives a WebSocket the three
things :meth:`.service.LodService.Session` uses of a grpc.aio call (write,
abort, the done callback), so a browser's session runs through the very same
code as a gRPC client's: limits, resume, drain, metrics and logs included.
What gRPC says in a status the browser gets as a final
``ServerMessage.status``, then a close code 4000 + the gRPC code.

Routes: ``/`` the viewer, ``/static/*`` its files (vendored; nothing comes
from a CDN, and the Content-Security-Policy says so), ``/v1/meshes`` the
ListMeshes answer (a serialized ListMeshesResponse), ``/v1/session`` the
WebSocket. docs/web.md describes the page and the protocol mapping.
"""

from __future__ import annotations

import asyncio
import hmac
import time
from importlib import resources

import grpc
from aiohttp import WSMsgType, web
from aiohttp.abc import AbstractAccessLogger

from .. import wire
from ..v1 import caveclod_pb2 as pb
from . import logs
from .session import Refused

SUBPROTOCOL = "caveclod.v1"
TOKEN_SUBPROTOCOL = "caveclod.bearer."    # + the token: how a browser sends one without a query string
CLOSE_REASON_BYTES = 123                  # RFC 6455: a close frame's reason
MAX_CLIENT_MESSAGE = 64 * 1024            # as gRPC's grpc.max_receive_message_length: RESOURCE_EXHAUSTED past it
# Past this, aiohttp drops the connection (close code 1009, no status) without
# reading the message: a bound on what one message may make the server buffer.
MAX_WEBSOCKET_MESSAGE = 4 * MAX_CLIENT_MESSAGE
STATIC = resources.files("caveclod") / "web"
# Only the page's own files: nothing from elsewhere can load, so a page that
# tried (a CDN left in by mistake) fails loudly in tests/test_web_chromium.py.
CSP = ("default-src 'self'; script-src 'self'; style-src 'self'; img-src 'self' data: blob:; "
       "connect-src 'self'; frame-ancestors 'none'")
CONTENT_TYPES = {".html": "text/html", ".js": "text/javascript", ".css": "text/css", ".txt": "text/plain",
                 ".ico": "image/x-icon"}


class Aborted(Exception):
    """Raised by :meth:`WebSocketCall.abort` after the status went out, as grpc.aio's abort raises."""


def close_code(code: grpc.StatusCode) -> int:
    """The WebSocket close code of a gRPC status: 1000 for OK, 4000 + the gRPC code otherwise."""
    return 1000 if code == grpc.StatusCode.OK else 4000 + code.value[0]


def status_message(code: grpc.StatusCode, message: str) -> bytes:
    """A serialized ServerMessage carrying the final status."""
    return pb.ServerMessage(status=pb.Status(code=code.value[0], message=message)).SerializeToString()


def _reason(message: str) -> str:
    """``message`` cut to a close frame's 123 bytes of UTF-8, on a character boundary."""
    data = message.encode()[:CLOSE_REASON_BYTES]
    return data.decode(errors="ignore")


GOING_AWAY = 1001
"""The close code a browser sends for a page's WebSockets when the page
unloads (the HTML standard): the page, and the session token it held in
memory, are gone, so its session ends instead of waiting to be resumed.
The page sends a Close first on ``pagehide``, but a message sent while
the page unloads may be dropped with the page. A dropped connection
(no close frame) or any other code leaves the session resumable."""


class WebSocketCall:
    """One WebSocket session as :class:`.service.LodService` sees a grpc.aio call.

    ``requests()`` yields the parsed ClientMessages (a WireError for bytes
    that do not parse, or a text message); when the connection ends it runs
    the done callbacks first, so that the session reads the end as a broken
    stream (resumable), not a half-close: a browser says goodbye with a
    Close message (the page does on unload), or closes with
    :data:`GOING_AWAY` as it unloads the page.
    """

    def __init__(self, ws: web.WebSocketResponse, peer: str, metrics):
        self.ws, self._peer, self.metrics = ws, peer, metrics
        self._callbacks: list = []
        self._done = False
        self.status_sent = False

    def peer(self) -> str:
        return self._peer

    def done(self) -> bool:
        return self._done or (self.ws.closed and not self._going_away())

    def _going_away(self) -> bool:
        """The page unloaded (:data:`GOING_AWAY`): its goodbye is the end of :meth:`requests`, a
        half-close. Frames written meanwhile are dropped instead of breaking the stream: written
        to the closed socket they raised, the session took that for a broken connection and kept
        the page's slot for --resume-ttl (5 of 5 tabs closed while frames flowed)."""
        return self.ws.close_code == GOING_AWAY

    def add_done_callback(self, callback) -> None:
        if self._done:
            callback(self)
        else:
            self._callbacks.append(callback)

    def mark_done(self) -> None:
        if not self._done:
            self._done = True
            for callback in self._callbacks:
                callback(self)
            self._callbacks.clear()

    async def write(self, data: bytes) -> None:
        if not self._done and self._going_away():
            return                            # nobody to read it: the session ends with the goodbye
        if self.done():
            raise ConnectionResetError("the WebSocket is closed")
        await self.ws.send_bytes(data)

    async def abort(self, code: grpc.StatusCode, message: str) -> None:
        await self.finish(code, message)
        raise Aborted(message)

    async def finish(self, code: grpc.StatusCode, message: str) -> None:
        """Send the final status (once) and close with its close code."""
        if self.status_sent:
            return
        self.status_sent = True
        if not self.ws.closed:
            try:
                data = status_message(code, message)
                await self.ws.send_bytes(data)
                self.metrics.bytes_out(len(data))
                await self.ws.close(code=close_code(code), message=_reason(message).encode())
            except ConnectionError:
                pass                          # the browser left first: nothing to tell
        self.mark_done()

    async def requests(self):
        """The client's messages, parsed; an oversized one raises Refused (RESOURCE_EXHAUSTED)."""
        try:
            async for msg in self.ws:
                if msg.type == WSMsgType.BINARY:
                    if len(msg.data) > MAX_CLIENT_MESSAGE:     # what gRPC answers to an oversized message
                        raise Refused(grpc.StatusCode.RESOURCE_EXHAUSTED,
                                      f"a client message of {len(msg.data)} bytes; the server accepts at most "
                                      f"{MAX_CLIENT_MESSAGE} (a pose is about 100)")
                    yield wire.parse_client_message(msg.data)
                elif msg.type == WSMsgType.TEXT:
                    yield wire.WireError("a text WebSocket message; send each ClientMessage serialized, "
                                         "as one binary message")
                else:                         # an error: the connection is gone
                    break
        except Refused:
            raise                             # the session ends with it (the stream is not broken)
        except Exception:
            self.mark_done()                  # the connection broke under the read
            raise
        if self.ws.close_code == GOING_AWAY:
            return                            # the page unloaded: a goodbye (a half-close), as a Close is
        self.mark_done()                      # the connection closed: a broken stream, not a half-close


def offered_token(request: web.Request) -> str | None:
    """The token a browser sent: ``?token=``, a ``caveclod.bearer.T`` subprotocol, or an
    ``authorization: Bearer`` header (non-browser clients); None when none."""
    if "token" in request.query:
        return request.query["token"]
    for offered in request.headers.get("Sec-WebSocket-Protocol", "").split(","):
        offered = offered.strip()
        if offered.startswith(TOKEN_SUBPROTOCOL):
            return offered[len(TOKEN_SUBPROTOCOL):]
    scheme, _, token = request.headers.get("Authorization", "").partition(" ")
    return token if scheme.lower() == "bearer" else None


def refusal(tokens, request: web.Request) -> str | None:
    """Why the request's token is refused, or None when it passes (or none is required)."""
    if not tokens:
        return None
    token = offered_token(request)
    if token is None:
        return ("the server requires a token; add ?token=T to the page's address (or offer the "
                f"WebSocket subprotocol '{TOKEN_SUBPROTOCOL}T')")
    # compare_digest against every token: no timing hint of a near miss. The header's bytes as sent:
    # one not UTF-8 (a browser sends Latin-1 for "ä") arrives surrogate-escaped, and encode() raised (500).
    offered = token.encode("utf-8", "surrogateescape")
    if any([hmac.compare_digest(offered, t.encode()) for t in tokens]):
        return None
    return "the token is not accepted; ask the server's operator for a valid one (?token=T)"


class AccessLog(AbstractAccessLogger):
    """One log event per HTTP request: method, path (never the query, which may hold a token), status."""

    def log(self, request, response, time_taken) -> None:
        logs.event("web.request", method=request.method, path=request.path, status=response.status,
                   ms=round(1000 * time_taken, 1), peer=request.remote)


class WebFront:
    """The HTTP server of ``--web-port``: page, static files, ListMeshes and WebSocket sessions.

    ``service`` is the server's :class:`.service.LodService`; sessions opened
    here count against the same ``--max-sessions``.
    """

    def __init__(self, service, config):
        self.service, self.config = service, config
        self.runner: web.AppRunner | None = None
        self.open_sockets: set[web.WebSocketResponse] = set()
        app = web.Application(client_max_size=MAX_CLIENT_MESSAGE, middlewares=[_headers])
        app.router.add_get("/", self.page)
        app.router.add_get("/static/{name}", self.static)
        app.router.add_get("/static/vendor/{name}", self.vendored)
        app.router.add_get("/v1/meshes", self.meshes)
        app.router.add_get("/v1/session", self.session)
        self.app = app

    async def start(self, host: str, port: int, reuse_port: bool = False) -> int:
        """Listen; the port bound."""
        self.runner = web.AppRunner(self.app, access_log_class=AccessLog, handle_signals=False,
                                    shutdown_timeout=1.0)
        await self.runner.setup()
        await web.TCPSite(self.runner, host, port, reuse_port=reuse_port or None).start()
        return self.runner.addresses[0][1]

    async def stop(self, grace: float = 1.0) -> None:
        """Stop: WebSockets whose sessions have ended (a drain) get ``grace`` seconds to send
        their status and close cleanly; any still open then is closed as UNAVAILABLE."""
        deadline = time.monotonic() + grace
        while self.open_sockets and time.monotonic() < deadline:
            await asyncio.sleep(0.02)
        for ws in list(self.open_sockets):
            await ws.close(code=close_code(grpc.StatusCode.UNAVAILABLE), message=b"the server stopped")
        if self.runner is not None:
            await self.runner.cleanup()
        # aiohttp keeps each (handler, app) it served in a module-level lru_cache
        # (web_app._build_middlewares), and our handlers are this object's methods: a stopped
        # front stays reachable, and through the service every mesh it served, its file
        # mapped (29 descriptors and the mapping per mesh, a test process reached 1,024).
        # Let go of the service so that only this small object stays.
        self.service = None

    async def page(self, request: web.Request) -> web.StreamResponse:
        return await self.static(request, "index.html")

    async def vendored(self, request: web.Request) -> web.StreamResponse:
        return await self.static(request, "vendor/" + request.match_info["name"])

    async def static(self, request: web.Request, name: str | None = None) -> web.StreamResponse:
        name = name or request.match_info["name"]
        suffix = name[name.rfind("."):] if "." in name else ""
        folder, _, base = name.rpartition("/")
        path = STATIC / folder / base if folder else STATIC / base
        # Only the page's own files: no other folder, no dot files, known types.
        if folder not in ("", "vendor") or "/" in base or base.startswith(".") or suffix not in CONTENT_TYPES \
                or not path.is_file():
            raise web.HTTPNotFound(text=f"no file {name!r} here; the viewer is at /")
        return web.Response(body=path.read_bytes(), content_type=CONTENT_TYPES[suffix],
                            headers={"Cache-Control": "no-cache"})

    async def meshes(self, request: web.Request) -> web.Response:
        why = refusal(self.config.tokens, request)
        if why is not None:
            raise web.HTTPUnauthorized(text=why)
        if self.service.sessions.draining:
            raise web.HTTPServiceUnavailable(text="the server is shutting down; ask another replica")
        return web.Response(body=self.service.catalogue.listing().SerializeToString(),
                            content_type="application/x-protobuf")

    async def session(self, request: web.Request) -> web.StreamResponse:
        ws = web.WebSocketResponse(protocols=(SUBPROTOCOL,), max_msg_size=MAX_WEBSOCKET_MESSAGE,
                                   heartbeat=self.config.keepalive_seconds, compress=False)
        if not ws.can_prepare(request).ok:
            raise web.HTTPBadRequest(text="this is caveclod's WebSocket endpoint: connect with a WebSocket "
                                          f"offering the subprotocol '{SUBPROTOCOL}'")
        await ws.prepare(request)
        self.open_sockets.add(ws)
        call = WebSocketCall(ws, f"web:{request.remote}", self.service.metrics)
        started = time.monotonic()
        try:
            why = refusal(self.config.tokens, request)
            if why is not None:                # refused after the upgrade: the page can show why
                logs.event("session.refused", code="UNAUTHENTICATED", message=why, peer=call.peer())
                await call.finish(grpc.StatusCode.UNAUTHENTICATED, why)
                return ws
            await self.service.Session(call.requests(), call)
            await call.finish(grpc.StatusCode.OK, "session closed")
        except Aborted:
            pass
        except Refused as r:                   # an oversized first message: no session to end
            await call.finish(r.code, r.message)
        except ConnectionError:
            pass                               # the browser left: the session stays resumable
        finally:
            call.mark_done()
            self.open_sockets.discard(ws)
            logs.event("web.session_ended", peer=call.peer(), seconds=round(time.monotonic() - started, 1),
                       close_code=ws.close_code)
        return ws


@web.middleware
async def _headers(request: web.Request, handler):
    """Every answer says where the page may load from (its own server only), and is not framed:
    refusals too (404, 401, 405 are raised, and skipped the headers when only what returned got them)."""
    try:
        response = await handler(request)
    except web.HTTPException as exc:
        _secure(exc)
        raise
    _secure(response)
    return response


def _secure(response) -> None:
    if not response.prepared:             # a WebSocket's headers went with its upgrade
        response.headers.setdefault("Content-Security-Policy", CSP)
        response.headers.setdefault("X-Content-Type-Options", "nosniff")
