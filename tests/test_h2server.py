"""caveclod serve --transport h2: what the service tests (run over both transports, tests/conftest.py)
do not reach: requests no gRPC client of ours sends, peers that are not HTTP/2, and the wire format of
statuses, spoken to by the h2 library as a raw client."""

from __future__ import annotations

import asyncio
import socket
import time

import grpc
import pytest

pytest.importorskip("h2", reason="the h2 library (the test extra) is not installed")
import h2.config  # noqa: E402
import h2.connection  # noqa: E402
import h2.events  # noqa: E402

from caveclod import http2  # noqa: E402
from caveclod.server.h2server import _deadline  # noqa: E402
from caveclod.v1 import caveclod_pb2 as pb  # noqa: E402


@pytest.fixture
def h2_server(make_server):
    return make_server(transport="h2")


def _connected(port: int, timeout: float = 5.0):
    """A raw h2 client connection that has the server's SETTINGS (its windows: a body may exceed the default)."""
    conn = h2.connection.H2Connection(h2.config.H2Configuration(client_side=True, header_encoding="utf-8"))
    conn.initiate_connection()
    sock = socket.create_connection(("127.0.0.1", port), timeout=timeout)
    sock.sendall(conn.data_to_send())
    while not any(isinstance(e, h2.events.RemoteSettingsChanged) for e in conn.receive_data(sock.recv(65536))):
        pass
    sock.sendall(conn.data_to_send())
    return conn, sock


def _request_headers(port: int, path: str, method: str = "POST", content_type: str = "application/grpc") -> list:
    return [(":method", method), (":scheme", "http"), (":path", path), (":authority", f"127.0.0.1:{port}"),
            ("te", "trailers"), ("content-type", content_type)]


def _raw_call(port: int, path: str, body: bytes, *, content_type: str = "application/grpc",
              end: bool = True, seconds: float = 10.0, method: str = "POST") -> dict:
    """One request over a fresh connection: the response's headers, data and trailers (or reset)."""
    out = {"headers": {}, "data": b"", "trailers": {}, "reset": None}
    conn, sock = _connected(port, seconds)
    with sock:
        conn.send_headers(1, _request_headers(port, path, method, content_type))
        step = conn.max_outbound_frame_size
        for i in range(0, max(len(body), 1), step):
            conn.send_data(1, body[i:i + step], end_stream=end and i + step >= len(body))
        sock.sendall(conn.data_to_send())
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline:
            data = sock.recv(65536)
            if not data:
                break
            done = False
            for event in conn.receive_data(data):
                if isinstance(event, h2.events.ResponseReceived):
                    out["headers"] = dict(event.headers)
                elif isinstance(event, h2.events.DataReceived):
                    out["data"] += event.data
                    conn.acknowledge_received_data(event.flow_controlled_length, event.stream_id)
                elif isinstance(event, h2.events.TrailersReceived):
                    out["trailers"] = dict(event.headers)
                elif isinstance(event, h2.events.StreamReset):
                    out["reset"] = event.error_code
                    done = True
                elif isinstance(event, h2.events.StreamEnded):
                    done = True
            sock.sendall(conn.data_to_send())
            if done:
                return out
    raise AssertionError(f"no end of the call within {seconds} s: {out}")


def _status(result: dict) -> tuple[int, str]:
    fields = {**result["headers"], **result["trailers"]}
    return int(fields["grpc-status"]), fields.get("grpc-message", "")


def _framed(message: bytes, flag: int = 0) -> bytes:
    return bytes([flag]) + len(message).to_bytes(4, "big") + message


def test_a_unary_call_answers_with_the_message_and_status_ok(h2_server):
    result = _raw_call(h2_server.port, "/caveclod.v1.Lod/ListMeshes", _framed(b""))
    assert result["headers"][":status"] == "200" and result["headers"]["content-type"] == "application/grpc"
    reply = pb.ListMeshesResponse.FromString(result["data"][5:])
    assert [m.name for m in reply.meshes] == ["terrain"] and _status(result) == (0, "")


@pytest.mark.parametrize("path, body, content_type, code, words", [
    ("/caveclod.v1.Lod/Nothing", _framed(b""), "application/grpc", grpc.StatusCode.UNIMPLEMENTED, "not found"),
    ("/caveclod.v1.Lod/ListMeshes", _framed(b"", flag=1), "application/grpc", grpc.StatusCode.UNIMPLEMENTED,
     "compressed"),
    ("/caveclod.v1.Lod/ListMeshes", _framed(b"x" * 70_000), "application/grpc",
     grpc.StatusCode.RESOURCE_EXHAUSTED, "at most 65536"),
    ("/caveclod.v1.Lod/ListMeshes", b"", "application/grpc", grpc.StatusCode.INTERNAL, "no request message"),
    ("/caveclod.v1.Lod/ListMeshes", _framed(b""), "text/plain", grpc.StatusCode.UNIMPLEMENTED, "not a gRPC request"),
    ("/caveclod.v1.Lod/ListMeshes", _framed(b"\xff\xff"), "application/grpc", grpc.StatusCode.INVALID_ARGUMENT,
     "undecodable"),
])
def test_a_request_that_cannot_be_served_ends_with_a_status_that_says_why(h2_server, path, body, content_type,
                                                                           code, words):
    result = _raw_call(h2_server.port, path, body, content_type=content_type)
    code_value, message = _status(result)
    assert code_value == code.value[0] and words in message.replace("%20", " "), (code_value, message)
    # gRPC's HTTP/2 mapping: 415 where the request is not gRPC's, so no HTTP client reads a 200 as success
    assert result["headers"][":status"] == ("200" if content_type == "application/grpc" else "415")


@pytest.mark.parametrize("end", [True, False])
def test_a_request_that_is_not_a_post_gets_405_and_the_connection_serves_on(h2_server, end):
    result = _raw_call(h2_server.port, "/caveclod.v1.Lod/ListMeshes", _framed(b""), method="PUT", end=end)
    assert result["headers"][":status"] == "405"
    code_value, message = _status(result)
    assert code_value == grpc.StatusCode.UNIMPLEMENTED.value[0] and "POST" in message, message
    assert _status(_raw_call(h2_server.port, "/caveclod.v1.Lod/ListMeshes", _framed(b""))) == (0, "")


def test_a_peer_that_is_not_http2_is_dropped_and_the_server_serves_on(h2_server):
    with socket.create_connection(("127.0.0.1", h2_server.port), timeout=5) as sock:
        sock.sendall(b"GET / HTTP/1.1\r\nHost: x\r\n\r\n")
        sock.settimeout(5)
        assert sock.recv(65536) is not None          # a SETTINGS and a GOAWAY, or nothing: then closed
    result = _raw_call(h2_server.port, "/caveclod.v1.Lod/ListMeshes", _framed(b""))
    assert _status(result) == (0, "")


def test_grpc_timeout_headers_set_deadlines():
    now = time.monotonic()
    assert abs(_deadline("250m") - now - 0.25) < 0.05 and abs(_deadline("3S") - now - 3) < 0.05
    assert abs(_deadline("1M") - now - 60) < 0.05 and _deadline(None) is None and _deadline("12x") is None


class _Standalone:
    """An H2Server with test handlers on an event loop of its own thread (no mesh, no kernels)."""

    def __init__(self, handlers: dict):
        import threading

        from caveclod.server.h2server import H2Server
        self.loop = asyncio.new_event_loop()
        self.thread = threading.Thread(target=self.loop.run_forever, daemon=True)
        self.thread.start()
        self.server = H2Server()
        self.server.add_generic_rpc_handlers((grpc.method_handlers_generic_handler("t.T", handlers),))
        self.port = self.server.add_insecure_port("127.0.0.1:0")
        self.call(self.server.start())

    def call(self, coroutine):
        return asyncio.run_coroutine_threadsafe(coroutine, self.loop).result(10)

    def state(self, fn):
        """fn() run on the server's loop (its state read safely)."""
        async def run():
            return fn()
        return self.call(run())

    def stop(self):
        self.call(self.server.stop(0))
        self.loop.call_soon_threadsafe(self.loop.stop)
        self.thread.join(5)


async def _hang(requests, context):
    """A handler that neither reads nor answers."""
    await asyncio.sleep(60)


async def _echo(requests, context):
    async for r in requests:
        await context.write(r)


def _open_calls(s) -> int:
    """Calls open on the standalone server ``s`` (read on its loop)."""
    return s.state(lambda: sum(len(c.calls) for c in s.server.connections))


@pytest.fixture
def standalone():
    made = []

    def make(handlers):
        made.append(_Standalone(handlers))
        return made[-1]
    yield make
    for s in made:
        s.stop()


def test_a_call_reset_in_the_read_that_opened_it_is_freed(standalone):
    s = standalone({"Hang": grpc.stream_stream_rpc_method_handler(_hang)})
    conn, sock = _connected(s.port)
    with sock:
        for sid in (1, 3, 5):                     # HEADERS and RST_STREAM in one write
            conn.send_headers(sid, _request_headers(s.port, "/t.T/Hang"))
            conn.reset_stream(sid)
        sock.sendall(conn.data_to_send())
        deadline = time.monotonic() + 5
        while time.monotonic() < deadline and _open_calls(s):
            time.sleep(0.05)
        assert _open_calls(s) == 0


def test_a_client_that_sends_faster_than_its_handler_reads_waits_for_its_window(standalone):
    from caveclod.server.h2server import STREAM_WINDOW

    s = standalone({"Slow": grpc.stream_stream_rpc_method_handler(_hang)})
    conn, sock = _connected(s.port)
    with sock:
        conn.send_headers(1, _request_headers(s.port, "/t.T/Slow"))
        message = _framed(b"p" * 995)
        sent, waiting = 0, False
        for _ in range(4):                         # four windows' worth, were the server to keep giving
            while conn.local_flow_control_window(1) >= len(message):
                conn.send_data(1, message)
                sent += len(message)
            sock.sendall(conn.data_to_send())
            time.sleep(0.3)
            sock.setblocking(False)
            try:
                conn.receive_data(sock.recv(65536))       # WINDOW_UPDATEs, if any came
            except BlockingIOError:
                waiting = True                            # none: the client waits
            sock.setblocking(True)
        queued = s.state(lambda: [sum(n for _, n in c.requests.queue) for conn_ in s.server.connections
                                  for c in conn_.calls.values()])
        assert waiting and sent <= STREAM_WINDOW and queued == [sent], (sent, queued)


def test_a_message_that_does_not_deserialize_ends_its_call_only(standalone):
    def strict(data: bytes):
        if data.startswith(b"BAD"):
            raise ValueError("cannot parse")
        return data

    s = standalone({"Echo": grpc.stream_stream_rpc_method_handler(_echo, request_deserializer=strict)})
    conn, sock = _connected(s.port)
    with sock:
        conn.send_headers(1, _request_headers(s.port, "/t.T/Echo"))
        conn.send_data(1, _framed(b"good"))
        sock.sendall(conn.data_to_send())
        time.sleep(0.2)
        conn.send_data(1, _framed(b"BAD"))
        sock.sendall(conn.data_to_send())
        trailers, deadline = None, time.monotonic() + 5
        while trailers is None and time.monotonic() < deadline:
            for event in conn.receive_data(sock.recv(65536)):
                if isinstance(event, h2.events.TrailersReceived):
                    trailers = dict(event.headers)
            sock.sendall(conn.data_to_send())
    assert trailers["grpc-status"] == str(grpc.StatusCode.INTERNAL.value[0])
    assert "does not deserialize" in trailers["grpc-message"].replace("%20", " ")
    # the connection serves on
    assert _status(_raw_call(s.port, "/t.T/Echo", _framed(b"fine"))) == (0, "")


def test_calls_still_open_when_the_server_stops_end_unavailable_with_a_status(standalone):
    """Past stop()'s grace a call ends with trailers (UNAVAILABLE: a client goes on elsewhere), not a
    cut socket, which a proxy in between would turn into an error of its own that clients do not retry."""

    async def hang(requests, context):
        await context.write(b"first")
        await asyncio.sleep(60)
    s = standalone({"Hang": grpc.stream_stream_rpc_method_handler(hang)})
    conn, sock = _connected(s.port)
    with sock:
        conn.send_headers(1, _request_headers(s.port, "/t.T/Hang"))
        sock.sendall(conn.data_to_send())
        events, deadline = [], time.monotonic() + 5
        while not any(isinstance(e, h2.events.DataReceived) for e in events) and time.monotonic() < deadline:
            events += conn.receive_data(sock.recv(65536))
        s.call(s.server.stop(0.2))
        # Read with caveclod's frame reader: the h2 library takes any frame after a GOAWAY for an
        # error, where RFC 9113 lets the streams the GOAWAY covers go on.
        reader, kinds, trailers, deadline = http2.FrameReader(1 << 24), [], None, time.monotonic() + 5
        while trailers is None and time.monotonic() < deadline:
            data = sock.recv(65536)
            if not data:
                break
            for kind, flags, stream_id, payload in reader.frames(data):
                kinds.append(kind)
                if kind == http2.GOAWAY:
                    assert int.from_bytes(payload[4:8], "big") == http2.NO_ERROR
                if kind == http2.HEADERS and flags & http2.END_STREAM and stream_id == 1:
                    trailers = {k: v for k, v in conn.decoder.decode(payload)}
    assert http2.GOAWAY in kinds and kinds.index(http2.GOAWAY) < kinds.index(http2.HEADERS), \
        "GOAWAY came first: no new streams"
    assert trailers is not None and trailers["grpc-status"] == str(grpc.StatusCode.UNAVAILABLE.value[0]), trailers
    assert "server stopped" in trailers["grpc-message"].replace("%20", " ")


def test_a_second_header_block_without_end_stream_resets_its_stream_only(standalone):
    """Trailers must end the stream (RFC 9113 8.1): a HEADERS in mid-call without END_STREAM is a
    malformed request, reset with PROTOCOL_ERROR; the connection serves on."""
    s = standalone({"Echo": grpc.stream_stream_rpc_method_handler(_echo)})
    conn, sock = _connected(s.port)
    with sock:
        conn.send_headers(1, _request_headers(s.port, "/t.T/Echo"))
        conn.send_data(1, _framed(b"one"))
        sock.sendall(conn.data_to_send())
        # h2 refuses to send such a block itself: frame it by hand, HPACK from h2's encoder.
        block = conn.encoder.encode([("x-late", "1")])
        sock.sendall(http2.frame(http2.HEADERS, http2.END_HEADERS, 1, block))
        reset, deadline = None, time.monotonic() + 5
        while reset is None and time.monotonic() < deadline:
            for event in conn.receive_data(sock.recv(65536)):
                if isinstance(event, h2.events.StreamReset):
                    reset = event.error_code
            sock.sendall(conn.data_to_send())
    assert reset == http2.PROTOCOL_ERROR
    assert _open_calls(s) == 0
    assert _status(_raw_call(s.port, "/t.T/Echo", _framed(b"fine"))) == (0, "")
