"""caveclod serve --transport h2: what the service tests (run over both transports, tests/conftest.py)
do not reach: requests no gRPC client of ours sends, peers that are not HTTP/2, and the wire format of
statuses, spoken to by the h2 library as a raw client."""

from __future__ import annotations

import socket
import time

import grpc
import pytest

pytest.importorskip("h2", reason="the h2 library (the test extra) is not installed")
import h2.config  # noqa: E402
import h2.connection  # noqa: E402
import h2.events  # noqa: E402

from caveclod.server.h2server import _deadline  # noqa: E402
from caveclod.v1 import caveclod_pb2 as pb  # noqa: E402


@pytest.fixture
def h2_server(make_server):
    return make_server(transport="h2")


def _raw_call(port: int, path: str, body: bytes, *, content_type: str = "application/grpc",
              end: bool = True, seconds: float = 10.0) -> dict:
    """One request over a fresh connection: the response's headers, data and trailers (or reset)."""
    conn = h2.connection.H2Connection(h2.config.H2Configuration(client_side=True, header_encoding="utf-8"))
    conn.initiate_connection()
    out = {"headers": {}, "data": b"", "trailers": {}, "reset": None}
    with socket.create_connection(("127.0.0.1", port), timeout=seconds) as sock:
        sock.sendall(conn.data_to_send())
        settings = False
        while not settings:                       # the server's windows first: a body may exceed the default
            events = conn.receive_data(sock.recv(65536))
            settings = any(isinstance(e, h2.events.RemoteSettingsChanged) for e in events)
        conn.send_headers(1, [(":method", "POST"), (":scheme", "http"), (":path", path),
                              (":authority", f"127.0.0.1:{port}"), ("te", "trailers"),
                              ("content-type", content_type)])
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
    code_value, message = _status(_raw_call(h2_server.port, path, body, content_type=content_type))
    assert code_value == code.value[0] and words in message.replace("%20", " "), (code_value, message)


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
