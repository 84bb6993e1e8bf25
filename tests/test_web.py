"""The web front (``--web-port``) from Python: the page and its files, ListMeshes
over HTTP, and caveclod.v1 sessions over WebSocket through the same session
machinery as gRPC (mirror equality, tokens, statuses, drain, resume, limits).

The browser itself is tested in tests/test_web_chromium.py.
"""

from __future__ import annotations

import asyncio
import logging

import aiohttp
import numpy as np
import pytest

from caveclod import paths
from caveclod.client import SessionProtocol
from caveclod.server import web
from caveclod.v1 import caveclod_pb2 as pb

from service import WAIT, wait_until
from webclient import OPTIONS, WsClient, ws_session


def _url(server, path="/v1/session", scheme="ws"):
    return f"{scheme}://127.0.0.1:{server.web_port}{path}"


def _run(coroutine):
    return asyncio.run(asyncio.wait_for(coroutine, WAIT))


def test_page_static_files_and_meshes(make_server):
    server = make_server(web_port=0)
    assert server.web.runner.addresses[0][0] == "127.0.0.1"        # the web port follows --host: loopback here

    async def go():
        async with aiohttp.ClientSession() as http:
            async with http.get(_url(server, "/", "http")) as r:
                assert r.status == 200 and "text/html" in r.headers["Content-Type"]
                assert "default-src 'self'" in r.headers["Content-Security-Policy"]
                page = await r.text()
            assert "viewer.js" in page
            async with http.get(_url(server, "/static/viewer.js", "http")) as r:
                assert r.status == 200 and r.headers["Content-Type"].startswith("text/javascript")
            for bad in ("/static/..%2Fserver%2Fweb.py", "/static/nothing.js", "/static/.hidden.js"):
                async with http.get(_url(server, bad, "http")) as r:
                    assert r.status == 404, bad
            async with http.get(_url(server, "/v1/meshes", "http")) as r:
                listing = pb.ListMeshesResponse.FromString(await r.read())
            assert [m.name for m in listing.meshes] == ["terrain"]
            async with http.get(_url(server, "/v1/session", "http")) as r:     # not a WebSocket
                assert r.status == 400 and "WebSocket" in await r.text()
            # Refusals are raised, and skipped the headers every answer is said to carry.
            for method, path, status in (("GET", "/static/nothing.js", 404), ("GET", "/nothing", 404),
                                         ("GET", "/v1/session", 400), ("OPTIONS", "/", 405), ("POST", "/", 405)):
                async with http.request(method, _url(server, path, "http")) as r:
                    assert r.status == status and "default-src 'self'" in r.headers.get(
                        "Content-Security-Policy", "") and r.headers.get("X-Content-Type-Options") == "nosniff", path
    _run(go())


def _flyover(n_poses: int, mirror_check=None):
    async def fly(client):
        p = client.protocol
        while not p.ready:
            assert await client.receive() is None or p.ready
        lo, hi = p.info.mesh.bounds_min, p.info.mesh.bounds_max
        lo, hi = (lo.x, lo.y, lo.z), (hi.x, hi.y, hi.z)
        for i in range(n_poses):
            pose = paths.flyover(lo, hi, 0, 2.0 * i)
            await client.send(p.pose_message(0, pose.eye, pose.target, pose.up))
            update = await client.receive()
            while update is not None and update.cameras.get(0) is not None \
                    and update.cameras[0].pose_seq < p.pose_seq:
                update = await client.receive()
            if mirror_check is not None:
                mirror_check(p)
        await client.send(p.close_message("done"))
    return fly


def test_websocket_session_equals_the_mirror_and_closes_ok(make_server):
    server = make_server(web_port=0)
    checked = []

    def check(p):
        mirror = server.sessions.sessions[p.token].cams[0].triangles()
        held = p.buffers.triangles(0)
        assert sorted(held) == sorted(mirror) and all(np.array_equal(held[k], mirror[k]) for k in held)
        checked.append(sum(len(t) for t in held.values()))

    client = _run(ws_session(_url(server), _flyover(12, check)))
    assert client.subprotocol == web.SUBPROTOCOL
    assert client.status.code == 0 and client.close_code == 1000
    assert client.protocol.divergences == 0 and client.protocol.bad_frames == 0
    assert len(checked) == 12 and max(checked) > 0
    assert wait_until(lambda: not server.sessions.sessions)         # a Close frees it at once


@pytest.mark.parametrize("encoding", ["raw", "ops"])
def test_both_frame_encodings(make_server, encoding):
    server = make_server(web_port=0)
    p = SessionProtocol("terrain", 1, OPTIONS, frame_encoding=encoding)
    client = _run(ws_session(_url(server), _flyover(6), protocol=p))
    assert client.status.code == 0 and p.divergences == 0 and p.last_applied >= 6


def test_a_bad_mesh_name_gets_not_found_with_the_message(make_server):
    server = make_server(web_port=0)
    client = _run(ws_session(_url(server), lambda c: asyncio.sleep(0), mesh="nope"))
    assert client.status.code == 5 and "nope" in client.status.message
    assert client.close_code == 4005


def test_a_text_message_is_refused(make_server):
    server = make_server(web_port=0)

    async def fly(client):
        await client.ws.send_str("hello")
    client = _run(ws_session(_url(server), fly))
    assert client.status.code == 3 and "binary" in client.status.message and client.close_code == 4003


def test_tokens_by_query_or_subprotocol_never_logged(make_server, tmp_path, caplog):
    server = make_server(web_port=0, tokens=("s3cret-token",))
    caplog.set_level(logging.INFO)
    # no token, a wrong one: UNAUTHENTICATED after the upgrade, with a message saying what to do
    for kwargs in ({}, {"query": "?token=wrong"}, {"token_protocol": "wrong"}):
        client = _run(ws_session(_url(server), lambda c: asyncio.sleep(0), **kwargs))
        assert client.status.code == 16 and "?token=" in client.status.message, kwargs
        assert client.close_code == 4016
    for kwargs in ({"query": "?token=s3cret-token"}, {"token_protocol": "s3cret-token"}):
        client = _run(ws_session(_url(server), _flyover(2), **kwargs))
        assert client.status.code == 0 and client.subprotocol == web.SUBPROTOCOL, kwargs

    async def listing(query):
        async with aiohttp.ClientSession() as http:
            async with http.get(_url(server, "/v1/meshes" + query, "http")) as r:
                return r.status
    assert _run(listing("")) == 401 and _run(listing("?token=s3cret-token")) == 200

    async def latin1(header: bytes) -> int:         # a browser's fetch sends "ä" as one Latin-1 byte
        reader, writer = await asyncio.open_connection("127.0.0.1", server.web_port)
        writer.write(b"GET /v1/meshes HTTP/1.1\r\nHost: x\r\nAuthorization: Bearer " + header + b"\r\n\r\n")
        await writer.drain()
        status = int((await reader.readline()).split()[1])
        writer.close()
        return status
    assert _run(latin1(b"p\xe4ss")) == 401, "a token not UTF-8 was a 500 (UnicodeEncodeError)"
    from caveclod.server.logs import JsonFormatter
    logged = "\n".join(JsonFormatter().format(r) for r in caplog.records)
    assert "s3cret-token" not in logged and "wrong" not in logged
    assert '"path": "/v1/session"' in logged and '"path": "/v1/meshes"' in logged   # an access log, without queries


def test_drain_ends_websocket_sessions_with_unavailable(make_server):
    server = make_server(web_port=0)

    async def fly(client):
        p = client.protocol
        while not p.ready:
            await client.receive()
        draining.append(asyncio.ensure_future(asyncio.to_thread(server.drain, 0.2)))   # read on meanwhile

    draining = []
    client = _run(ws_session(_url(server), fly))
    assert client.status.code == 14 and client.status.message
    assert client.close_code == 4014


def test_a_dropped_websocket_leaves_the_session_resumable(make_server):
    server = make_server(web_port=0, resume_ttl=30)
    p = SessionProtocol("terrain", 1, OPTIONS, frame_encoding="raw")

    async def first():
        async with aiohttp.ClientSession() as http:
            async with http.ws_connect(_url(server), protocols=[web.SUBPROTOCOL]) as ws:
                client = WsClient(ws, p)
                await client.send(p.open_message())
                while not p.ready:
                    await client.receive()
                lo, hi = p.info.mesh.bounds_min, p.info.mesh.bounds_max
                pose = paths.circle((lo.x, lo.y, lo.z), (hi.x, hi.y, hi.z), 0, 0.0)
                await client.send(p.pose_message(0, pose.eye, pose.target, pose.up))
                await client.receive()
        # the connection dropped without a Close (a tab's network went away)
    _run(first())
    token = p.token
    assert wait_until(lambda: token in server.sessions.sessions and server.sessions.counts()[0] == 0)
    client = _run(ws_session(_url(server), _flyover(2), protocol=p))
    assert p.info.resumed and p.token == token and client.status.code == 0 and p.divergences == 0


def test_a_websocket_closed_as_its_page_unloads_ends_the_session(make_server):
    """Close code 1001 (going away: what a browser sends for a page it unloads) ends the session
    even when the page's Close message was lost with the page; the resumable drop above sent 1000."""
    server = make_server(web_port=0, resume_ttl=30)
    p = SessionProtocol("terrain", 1, OPTIONS, frame_encoding="raw")

    async def leave():
        async with aiohttp.ClientSession() as http:
            ws = await http.ws_connect(_url(server), protocols=[web.SUBPROTOCOL])
            client = WsClient(ws, p)
            await client.send(p.open_message())
            while not p.ready:
                await client.receive()
            await ws.close(code=web.GOING_AWAY)
    _run(leave())
    assert wait_until(lambda: not server.sessions.sessions, timeout=10), "left resumable for the TTL"


def test_websocket_and_grpc_sessions_share_the_limit(make_server):
    from service import Driver
    server = make_server(web_port=0, max_sessions=1)
    driver = Driver(server.port, SessionProtocol("terrain", 1, OPTIONS))
    try:
        assert wait_until(lambda: server.sessions.counts()[0] == 1)
        client = _run(ws_session(_url(server), lambda c: asyncio.sleep(0)))
        assert client.status.code == 8 and client.close_code == 4008
    finally:
        driver.close()


def test_close_codes_and_reasons_fit_websocket_limits():
    import grpc
    assert web.close_code(grpc.StatusCode.OK) == 1000
    assert web.close_code(grpc.StatusCode.UNAUTHENTICATED) == 4016
    long = "é" * 200
    assert len(web._reason(long).encode()) <= 123 and web._reason(long).startswith("é")


def test_the_vendored_messages_follow_the_proto(tmp_path):
    """caveclod/web/vendor/caveclod_pb.js, generated from the .proto by web/build.mjs, knows every
    message and field (regenerate it after editing the .proto); byte for byte where npm's tools are here."""
    import shutil
    import subprocess
    from pathlib import Path
    text = (web.STATIC / "vendor" / "caveclod_pb.js").read_text()
    for message in pb.DESCRIPTOR.message_types_by_name.values():
        assert f"v1.{message.name} = (function" in text, f"{message.name}: run `cd web && npm ci && npm run build`"
        for field in message.fields:
            camel = field.name.split("_")[0] + "".join(w.title() for w in field.name.split("_")[1:])
            assert f"{message.name}.prototype.{camel} =" in text, f"{message.name}.{field.name}: rebuild web/"
    web_dir = Path(__file__).resolve().parents[1] / "web"
    if shutil.which("node") and (web_dir / "node_modules" / "protobufjs-cli").is_dir():
        subprocess.run(["node", str(web_dir / "build.mjs"), str(tmp_path)], check=True, capture_output=True, timeout=120)
        assert (tmp_path / "caveclod_pb.js").read_bytes() == (web.STATIC / "vendor" / "caveclod_pb.js").read_bytes()


@pytest.mark.parametrize("after_open", [False, True])
def test_an_oversized_message_gets_resource_exhausted_as_over_grpc(make_server, after_open):
    server = make_server(web_port=0)
    big = pb.ClientMessage(keyframe_request=pb.KeyframeRequest(detail="x" * (web.MAX_CLIENT_MESSAGE + 100)))

    async def go():
        async with aiohttp.ClientSession() as http:
            async with http.ws_connect(_url(server), protocols=[web.SUBPROTOCOL]) as ws:
                if after_open:
                    await ws.send_bytes(SessionProtocol("terrain", 1, OPTIONS).open_message().SerializeToString())
                await ws.send_bytes(big.SerializeToString())
                status = None
                while (msg := await ws.receive(timeout=WAIT)).type == aiohttp.WSMsgType.BINARY:
                    reply = pb.ServerMessage.FromString(msg.data)
                    if reply.WhichOneof("kind") == "status":
                        status = reply.status
                return status, ws.close_code
    status, close_code = _run(go())
    assert status.code == 8 and "at most 65536" in status.message and close_code == 4008
    assert wait_until(lambda: not server.sessions.sessions)


def test_a_web_port_in_use_is_a_clear_error(make_server):
    import socket

    from caveclod.errors import CaveclodError
    with socket.socket() as held:
        held.bind(("127.0.0.1", 0))
        held.listen()
        with pytest.raises(CaveclodError, match="cannot listen on 127.0.0.1:.* for the viewer.*--web-port"):
            make_server(web_port=held.getsockname()[1], web_host="127.0.0.1")


def test_a_stopped_server_with_a_web_port_lets_go_of_its_meshes(terrain_path):
    """aiohttp keeps every (handler, app) it served in a module-level cache, and the handlers are
    the web front's methods: a stopped server stayed reachable with every mesh it served mapped
    (29 descriptors a mesh; a test process ran out at 1,024). Stopped, nothing holds them."""
    import gc
    import weakref
    from caveclod.server import LodServer, ServerConfig
    server = LodServer(ServerConfig(meshes=[str(terrain_path)], host="127.0.0.1", port=0, web_port=0)).start()
    try:
        assert server.sessions.ready.wait(60)

        async def fetch(url):
            async with aiohttp.ClientSession() as http:
                async with http.get(url) as r:
                    assert r.status == 200
        _run(fetch(_url(server, "/v1/meshes", "http")))
        mesh = weakref.ref(next(iter(server.catalogue.meshes.values())).mesh)
    finally:
        server.stop(grace=0)
    del server
    import threading
    for thread in threading.enumerate():     # its warm-up (packing after ready) and reaper end soon after
        if thread.name in ("caveclod-warm-up", "caveclod-reaper"):
            thread.join(timeout=30)
    gc.collect()
    assert mesh() is None


def test_a_page_that_goes_away_ends_its_session_even_with_frames_to_write():
    """A close with 1001 (a tab closed) ends the session with the end of its requests, but a frame
    written once the close had arrived raised (the socket was closed), and the session took that
    for a broken connection: kept resumable for --resume-ttl, it held its slot and the next tab
    was refused (5 of 5 tabs closed while frames flowed, in a sweep)."""
    from types import SimpleNamespace
    from caveclod.server.web import GOING_AWAY, WebSocketCall
    sent = []

    async def send_bytes(data):
        sent.append(data)
    for close_code, raises in ((GOING_AWAY, False), (1006, True), (1000, True)):
        ws = SimpleNamespace(closed=True, close_code=close_code, send_bytes=send_bytes)
        call = WebSocketCall(ws, "peer", None)
        assert call.done() is raises, close_code
        if raises:
            with pytest.raises(ConnectionResetError):
                _run(call.write(b"frame"))
        else:
            _run(call.write(b"frame"))                     # dropped: nobody reads it, nothing breaks
    assert sent == []
