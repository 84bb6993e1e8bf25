"""`caveclod loadtest --transport h2`: gRPC over HTTP/2, framed by caveclod.client.h2wire.

The framing against a scripted HTTP/2 server (the h2 library's server side) (every way a call can end, and
a peer that is not gRPC or not HTTP/2), then load tests through a network
cut (sessions resume with their tokens) and across a server restart (they
fail over to fresh sessions), with every CRC checked.
"""

from __future__ import annotations

import asyncio
import json
import threading

import grpc
import pytest

pytest.importorskip("hpack", reason="the hpack library (the loadtest extra) is not installed")
pytest.importorskip("h2", reason="the h2 library (the test extra; the scripted servers) is not installed")
import h2.config  # noqa: E402
import h2.connection  # noqa: E402
import h2.events  # noqa: E402

from caveclod import cli  # noqa: E402
from caveclod.client.h2session import H2Target  # noqa: E402
from caveclod.client.h2wire import MAX_MESSAGE, CallEnded  # noqa: E402
from failover import free_port  # noqa: E402
from service import proxy_to, wait_until  # noqa: E402

OK_HEADERS = [(":status", "200"), ("content-type", "application/grpc")]


def framed(message: bytes, compressed: bool = False, size: int | None = None) -> bytes:
    """One gRPC message as it travels: flag, big-endian length, bytes."""
    return bytes([compressed]) + (len(message) if size is None else size).to_bytes(4, "big") + message


async def _scripted(respond):
    """An HTTP/2 server on 127.0.0.1:0 that answers every request with ``respond(conn, stream_id)``."""
    async def handle(reader, writer):
        conn = h2.connection.H2Connection(h2.config.H2Configuration(client_side=False, header_encoding="utf-8"))
        conn.initiate_connection()
        writer.write(conn.data_to_send())
        try:
            while data := await reader.read(65536):
                for event in conn.receive_data(data):
                    if isinstance(event, h2.events.RequestReceived):
                        respond(conn, event.stream_id)
                writer.write(conn.data_to_send())
        except (ConnectionError, h2.exceptions.ProtocolError):
            pass
        writer.close()
    return await asyncio.start_server(handle, "127.0.0.1", 0)


def _unary(respond, request: bytes = b"ping"):
    """The reply of one unary call to a scripted server, or the CallEnded it raised."""
    async def main():
        server = await _scripted(respond)
        target = H2Target("127.0.0.1", server.sockets[0].getsockname()[1])
        try:
            return await target.unary("/t.T/M", request, timeout=5.0)
        except CallEnded as exc:
            return exc
        finally:
            target.close()
            server.close()
    return asyncio.run(asyncio.wait_for(main(), 20))


def test_a_reply_split_over_frames_arrives_whole():
    def respond(conn, sid):
        body = framed(b"x" * 40_000)
        conn.send_headers(sid, OK_HEADERS)
        for i in range(0, len(body), 7_000):          # cut anywhere, the prefix included
            conn.send_data(sid, body[i:i + 7_000])
        conn.send_headers(sid, [("grpc-status", "0")], end_stream=True)
    assert _unary(respond) == b"x" * 40_000


@pytest.mark.parametrize("case, code, words", [
    ("trailers only", grpc.StatusCode.NOT_FOUND, "no mesh named terrain"),
    ("http 404", grpc.StatusCode.UNIMPLEMENTED, "HTTP status 404"),
    ("compressed", grpc.StatusCode.INTERNAL, "compressed"),
    ("huge", grpc.StatusCode.RESOURCE_EXHAUSTED, f"at most {MAX_MESSAGE}"),
    ("cut short", grpc.StatusCode.INTERNAL, "inside a message"),
    ("no status", grpc.StatusCode.UNKNOWN, "without a grpc-status"),
    ("reset", grpc.StatusCode.INTERNAL, "RST_STREAM"),
    ("two replies", grpc.StatusCode.INTERNAL, "2 replies to a unary call"),
    ("goaway", grpc.StatusCode.UNAVAILABLE, "GOAWAY"),
    ("status not a number", grpc.StatusCode.UNKNOWN, "not a number"),
])
def test_every_way_a_call_ends_is_a_status_that_says_why(case, code, words):
    def respond(conn, sid):
        if case == "trailers only":
            conn.send_headers(sid, OK_HEADERS + [("grpc-status", "5"), ("grpc-message", "no%20mesh%20named%20terrain")],
                              end_stream=True)
        elif case == "http 404":
            conn.send_headers(sid, [(":status", "404")], end_stream=True)
        elif case == "goaway":
            conn.close_connection(last_stream_id=0)
        elif case == "status not a number":
            conn.send_headers(sid, OK_HEADERS + [("grpc-status", "five")], end_stream=True)
        elif case == "reset":
            conn.send_headers(sid, OK_HEADERS)
            conn.reset_stream(sid, error_code=2)
        else:
            conn.send_headers(sid, OK_HEADERS)
            body = {"compressed": framed(b"abc", compressed=True), "huge": framed(b"", size=MAX_MESSAGE + 1),
                    "cut short": framed(b"abcdef")[:7], "no status": framed(b"abc"),
                    "two replies": framed(b"a") + framed(b"b")}[case]
            conn.send_data(sid, body, end_stream=case == "no status")
            if case != "no status":
                conn.send_headers(sid, [("grpc-status", "0")], end_stream=True)
    result = _unary(respond)
    assert isinstance(result, CallEnded), result
    assert result.code == code and words in result.details, (result.code, result.details)


def test_flow_control_padding_pings_and_split_header_blocks(monkeypatch):
    """What a plain reply does not exercise: a request larger than the server's window (it waits for
    WINDOW_UPDATEs), padded DATA, a PING to answer, and trailers split over CONTINUATION frames."""
    from caveclod.client import h2wire
    monkeypatch.setattr(h2wire, "MAX_FRAME", 16384)        # so that h2 splits a long header block
    seen = {"pings": 0}

    async def main():
        async def handle(reader, writer):
            conn = h2.connection.H2Connection(h2.config.H2Configuration(client_side=False, header_encoding="utf-8"))
            conn.initiate_connection()
            writer.write(conn.data_to_send())
            body = bytearray()
            while data := await reader.read(65536):
                for event in conn.receive_data(data):
                    if isinstance(event, h2.events.DataReceived):
                        body += event.data
                        conn.acknowledge_received_data(event.flow_controlled_length, event.stream_id)
                    elif isinstance(event, h2.events.PingAckReceived):
                        seen["pings"] += 1
                    elif isinstance(event, h2.events.StreamEnded):
                        sid = event.stream_id
                        conn.ping(b"12345678")
                        conn.send_headers(sid, OK_HEADERS)
                        conn.send_data(sid, framed(str(len(body)).encode()), pad_length=17)
                        conn.send_headers(sid, [("grpc-status", "0"), ("grpc-message", "x" * 40_000)],
                                          end_stream=True)
                writer.write(conn.data_to_send())
            writer.close()
        server = await asyncio.start_server(handle, "127.0.0.1", 0)
        target = H2Target("127.0.0.1", server.sockets[0].getsockname()[1])
        try:
            reply = await target.unary("/t.T/M", b"r" * 300_000, timeout=5.0)
            await asyncio.sleep(0.05)                   # the PING's ACK left with the reply's read
            return reply
        finally:
            target.close()
            server.close()
    assert asyncio.run(asyncio.wait_for(main(), 20)) == str(5 + 300_000).encode()
    assert seen["pings"] == 1


def test_a_peer_that_is_not_http2_or_not_there_is_unavailable():
    async def main():
        async def http1(reader, writer):
            await reader.read(100)
            writer.write(b"HTTP/1.1 400 Bad Request\r\nContent-Length: 0\r\n\r\n")
            await writer.drain()
            writer.close()
        server = await asyncio.start_server(http1, "127.0.0.1", 0)
        port = server.sockets[0].getsockname()[1]
        results = []
        for p in (port, free_port()):
            target = H2Target("127.0.0.1", p)
            try:
                results.append(await target.unary("/t.T/M", b"", timeout=5.0))
            except CallEnded as exc:
                results.append(exc)
            finally:
                target.close()
        server.close()
        return results
    garbled, nobody = asyncio.run(asyncio.wait_for(main(), 20))
    assert garbled.code == grpc.StatusCode.UNAVAILABLE and "HTTP/2" in garbled.details, garbled
    assert nobody.code == grpc.StatusCode.UNAVAILABLE and "cannot connect" in nobody.details, nobody


def test_a_connection_going_away_is_replaced_for_the_next_call():
    answered = []

    def respond(conn, sid):
        if not answered:                       # the first call is refused by a server going away
            answered.append(sid)
            conn.close_connection(last_stream_id=0)
            return
        conn.send_headers(sid, OK_HEADERS)
        conn.send_data(sid, framed(b"fine"))
        conn.send_headers(sid, [("grpc-status", "0")], end_stream=True)

    async def main():
        server = await _scripted(respond)
        target = H2Target("127.0.0.1", server.sockets[0].getsockname()[1])
        try:
            with pytest.raises(CallEnded, match="GOAWAY"):
                await target.unary("/t.T/M", b"", timeout=5.0)
            first = target.conn
            reply = await target.unary("/t.T/M", b"", timeout=5.0)
            return reply, first is not target.conn
        finally:
            target.close()
            server.close()
    assert asyncio.run(asyncio.wait_for(main(), 20)) == (b"fine", True)


def test_a_server_message_that_does_not_parse_ends_the_session_with_data_loss():
    from caveclod.client.h2session import H2Session
    from caveclod.client.protocol import SessionProtocol
    from caveclod.client.session import refine_options

    def respond(conn, sid):
        conn.send_headers(sid, OK_HEADERS)
        conn.send_data(sid, framed(b"\xff\xff\xff\xff"))      # not a ServerMessage

    async def main():
        server = await _scripted(respond)
        target = H2Target("127.0.0.1", server.sockets[0].getsockname()[1])
        ends = []
        protocol = SessionProtocol("m", 1, refine_options(64, 64, None, None, None, None, None, None))
        session = H2Session(target, protocol, on_frame=lambda f: None, on_end=ends.append)
        try:
            await session.open()
            with pytest.raises(Exception) as info:
                await asyncio.wait_for(session.ready, 5.0)
            return info.value, ends
        finally:
            target.close()
            server.close()
    error, ends = asyncio.run(asyncio.wait_for(main(), 20))
    assert len(ends) == 1 and ends[0] is error
    assert error.code == grpc.StatusCode.DATA_LOSS and "does not parse" in error.details


def _loadtest(port: int, tmp_path, capsys, *extra: str) -> tuple[int, dict]:
    status = cli.main(["loadtest", "--target", f"127.0.0.1:{port}", "--sessions", "3", "--duration", "4",
                       "--rate", "20", "--transport", "h2", "--json", "--cache-dir", str(tmp_path / "cache"),
                       *extra])
    return status, json.loads(capsys.readouterr().out)


def test_sessions_resume_with_their_tokens_after_a_network_cut(server, tmp_path, capsys):
    stop = threading.Event()

    def cut_mid_flight():
        # Once all three sessions are open and have flown a moment (about 0.6 s
        # after the start here; a fixed 2.5 s cut came before the opens on a
        # loaded machine, and nothing resumed).
        if wait_until(lambda: stop.is_set() or server.sessions.counts()[0] == 3, timeout=20) and not stop.wait(0.8):
            proxy.cut()

    with proxy_to(server.port) as proxy:
        cutter = threading.Thread(target=cut_mid_flight, daemon=True)
        cutter.start()
        try:
            status, report = _loadtest(proxy.port, tmp_path, capsys, "--duration", "6")
        finally:
            stop.set()
            cutter.join(10)
    assert status == 0, report
    assert report["transport"] == "h2" and report["errors"] == {}
    assert report["resumes"] == 3 and report["failovers"] == 0
    assert report["divergences"] == 0 and report["bad_frames"] == 0
    assert report["frames"] >= 3 * 20 * 3, "frames kept coming after the cut"


def test_sessions_fail_over_to_fresh_ones_when_the_server_restarts(make_server, tmp_path, capsys):
    port = free_port()
    first = make_server(port=port)
    restarted = []

    def restart():
        first.stop(grace=0)
        restarted.append(make_server(port=port))
    swap = threading.Timer(2.5, restart)
    swap.start()
    try:
        # 6 s: room for a slow restart (the sessions retry with backoff meanwhile).
        status, report = _loadtest(port, tmp_path, capsys, "--duration", "6")
    finally:
        swap.cancel()
        swap.join(60)
    assert restarted, "the second server did not start"
    assert status == 0, report
    assert report["errors"] == {} and report["divergences"] == 0 and report["bad_frames"] == 0
    assert report["failovers"] == 3 and report["resumes"] == 0, "the new server knows no token: fresh sessions"
    assert report["keyframes"] >= 6, "each session's first frame, and its fresh session's"
    assert restarted[0].metrics.total("frames") > 0


def test_a_server_that_dies_mid_run_is_an_error_not_a_pass(make_server, tmp_path, capsys):
    """Sessions still waiting to resume when the run ended were closed as "not connected", no error:
    a load test whose server died within the retries' 9-17 s reported errors {} and exited 0."""
    server = make_server(port=free_port())
    stop = threading.Event()

    def kill_mid_flight():
        if wait_until(lambda: stop.is_set() or server.sessions.counts()[0] == 3, timeout=20) and not stop.wait(0.5):
            server.stop(grace=0)
    killer = threading.Thread(target=kill_mid_flight, daemon=True)
    killer.start()
    try:
        status, report = _loadtest(server.port, tmp_path, capsys)
    finally:
        stop.set()
        killer.join(30)
    assert status == 1, report
    assert report["errors"] == {"UNAVAILABLE": 3} and report["frames"] > 0


def test_sessions_a_server_never_opens_are_errors_not_a_hang(tmp_path, capsys):
    """A server that lists a mesh but never answers an Open: each session counts DEADLINE_EXCEEDED."""
    from caveclod.v1 import caveclod_pb2 as pb
    listing = pb.ListMeshesResponse(meshes=[pb.MeshInfo(name="mute", bounds_max=pb.Vec3(x=1, y=1, z=1))])

    def respond(conn, sid):
        conn.send_headers(sid, OK_HEADERS)
        if sid == 1:                                   # ListMeshes, the first call
            conn.send_data(sid, framed(listing.SerializeToString()))
            conn.send_headers(sid, [("grpc-status", "0")], end_stream=True)
        # A Session call: headers, then nothing.

    loop = asyncio.new_event_loop()
    server = loop.run_until_complete(_scripted(respond))
    thread = threading.Thread(target=loop.run_forever, daemon=True)
    thread.start()
    try:
        status = cli.main(["loadtest", "--target", f"127.0.0.1:{server.sockets[0].getsockname()[1]}",
                           "--sessions", "2", "--connections", "1", "--duration", "1", "--transport", "h2",
                           "--json", "--cache-dir", str(tmp_path)])
    finally:
        loop.call_soon_threadsafe(server.close)
        loop.call_soon_threadsafe(loop.stop)
        thread.join(10)
    out, err = capsys.readouterr()
    report = json.loads(out)
    assert status == 1 and report["errors"] == {"DEADLINE_EXCEEDED": 2} and report["frames"] == 0
    assert "no SessionInfo" in err


def test_h2_needs_plaintext(server, capsys):
    assert cli.main(["loadtest", "--target", f"127.0.0.1:{server.port}", "--transport", "h2",
                     "--tls-ca", "ca.pem"]) == 2
    assert "plaintext" in capsys.readouterr().err
