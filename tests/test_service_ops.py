"""Operations: health, reflection, Prometheus metrics, bearer tokens, TLS, logs."""

from __future__ import annotations

import datetime
import io
import json
import logging
import urllib.request

import grpc
import pytest
from grpc_health.v1 import health_pb2, health_pb2_grpc

from caveclod.v1 import caveclod_pb2 as pb

from service import open_message, raw_stream, wait_until


def health_status(port: int, service: str = "", credentials=None, server_name=None) -> int:
    options = [("grpc.ssl_target_name_override", server_name)] if server_name else []
    target = f"127.0.0.1:{port}"
    with (grpc.insecure_channel(target) if credentials is None
          else grpc.secure_channel(target, credentials, options)) as channel:
        stub = health_pb2_grpc.HealthStub(channel)
        return stub.Check(health_pb2.HealthCheckRequest(service=service), timeout=10).status


def test_health_serving_then_not_serving_while_draining(make_server):
    server = make_server(drain_seconds=5)
    for name in ("", "caveclod.v1.Lod"):
        assert health_status(server.port, name) == health_pb2.HealthCheckResponse.SERVING
    from caveclod.client import Client, SessionEnded
    client = Client(f"127.0.0.1:{server.port}", cache_dir=False)
    session = client.session("terrain", width=64, height=64)
    import threading
    drainer = threading.Thread(target=server.drain)
    drainer.start()
    try:
        assert wait_until(lambda: server.sessions.draining)
        assert health_status(server.port) == health_pb2.HealthCheckResponse.NOT_SERVING
        code, details, _ = raw_stream(server.port, [open_message()])
        assert code == grpc.StatusCode.UNAVAILABLE and "shutting down" in details
        with pytest.raises(grpc.RpcError) as err:
            client.list_meshes()
        assert err.value.code() == grpc.StatusCode.UNAVAILABLE
        session.close()                  # the last session leaves: the drain ends early
    finally:
        drainer.join(20)
        client.close()
    assert not drainer.is_alive()
    with pytest.raises(SessionEnded):
        Client(f"127.0.0.1:{server.port}", cache_dir=False).session("terrain", timeout=2, width=64, height=64)


def test_reflection_lists_the_services(server):
    from grpc_reflection.v1alpha import reflection_pb2, reflection_pb2_grpc
    with grpc.insecure_channel(f"127.0.0.1:{server.port}") as channel:
        stub = reflection_pb2_grpc.ServerReflectionStub(channel)
        reply = next(stub.ServerReflectionInfo(iter([reflection_pb2.ServerReflectionRequest(list_services="")]),
                                               timeout=10))
    names = {s.name for s in reply.list_services_response.service}
    assert {"caveclod.v1.Lod", "grpc.health.v1.Health"} <= names


def test_prometheus_metrics(make_server, tmp_path):
    server = make_server(metrics_port=0, metrics_host="127.0.0.1")
    from caveclod.client import Client
    from caveclod.paths import flyover
    with Client(f"127.0.0.1:{server.port}", cache_dir=tmp_path) as client:
        with client.session("terrain", width=640, height=360) as s:
            lo, hi = s.vertex_buffer.positions.min(0), s.vertex_buffer.positions.max(0)
            for i in range(5):
                seq = s.send_pose(0, *flyover(lo, hi, 0, i / 30))
                while s.next_frame(timeout=5).pose_seq < seq:
                    pass
            text = urllib.request.urlopen(f"http://127.0.0.1:{server.metrics_port}/metrics", timeout=10).read().decode()
    values = {line.split(" ")[0]: float(line.split(" ")[1]) for line in text.splitlines()
              if line and not line.startswith("#")}
    assert values["caveclod_sessions_active"] == 1
    assert values["caveclod_sessions_resumable"] == 0
    assert values["caveclod_frames_total"] >= 5, values
    assert values["caveclod_bytes_sent_total"] > s.info.vertex_packing.packed_bytes      # the download counts
    assert values["caveclod_refine_seconds_count"] >= 5
    assert values["caveclod_pose_to_frame_seconds_count"] >= 5


@pytest.fixture
def token_server(make_server):
    return make_server(tokens=("s3cret-one", "s3cret-two"))


def test_a_token_is_required_but_health_stays_open(token_server):
    port = token_server.port
    code, details, _ = raw_stream(port, [open_message()])
    assert code == grpc.StatusCode.UNAUTHENTICATED and "authorization" in details
    assert raw_stream(port, [open_message()], metadata=(("authorization", "Bearer wrong"),))[0] == \
        grpc.StatusCode.UNAUTHENTICATED
    assert raw_stream(port, [open_message()], metadata=(("authorization", "Basic s3cret-one"),))[0] == \
        grpc.StatusCode.UNAUTHENTICATED
    code, _, responses = raw_stream(port, [open_message()], timeout=1.0,
                                    metadata=(("authorization", "Bearer s3cret-two"),))
    assert responses and responses[0].WhichOneof("kind") == "session_info"
    assert health_status(port) == health_pb2.HealthCheckResponse.SERVING
    from caveclod.client import Client
    with pytest.raises(grpc.RpcError) as err:
        Client(f"127.0.0.1:{port}", cache_dir=False).list_meshes()
    assert err.value.code() == grpc.StatusCode.UNAUTHENTICATED
    with Client(f"127.0.0.1:{port}", token="s3cret-one", cache_dir=False) as client:
        assert [m.name for m in client.list_meshes()] == ["terrain"]
        with client.session("terrain", width=64, height=64) as s:
            assert s.next_frame(timeout=5).frame_seq == 1


def self_signed(tmp_path):
    """(certificate PEM, key PEM) for 'localhost' and 127.0.0.1, made with cryptography."""
    import ipaddress

    from cryptography import x509
    from cryptography.hazmat.primitives import hashes, serialization
    from cryptography.hazmat.primitives.asymmetric import ec
    from cryptography.x509.oid import NameOID
    key = ec.generate_private_key(ec.SECP256R1())
    name = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, "localhost")])
    now = datetime.datetime.now(datetime.timezone.utc)
    cert = (x509.CertificateBuilder().subject_name(name).issuer_name(name).public_key(key.public_key())
            .serial_number(x509.random_serial_number()).not_valid_before(now - datetime.timedelta(minutes=5))
            .not_valid_after(now + datetime.timedelta(days=1))
            .add_extension(x509.SubjectAlternativeName([x509.DNSName("localhost"),
                                                        x509.IPAddress(ipaddress.ip_address("127.0.0.1"))]), False)
            .add_extension(x509.BasicConstraints(ca=True, path_length=None), True)
            .sign(key, hashes.SHA256()))
    return (cert.public_bytes(serialization.Encoding.PEM),
            key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8,
                              serialization.NoEncryption()))


def test_tls_with_a_token(make_server, tmp_path):
    cert, key = self_signed(tmp_path)
    server = make_server(tls_cert=cert, tls_key=key, tokens=("tls-token",))
    from caveclod.client import Client
    with Client(f"127.0.0.1:{server.port}", tls_ca=cert, token="tls-token", cache_dir=tmp_path) as client:
        with client.session("terrain", width=64, height=64) as s:
            assert s.next_frame(timeout=5).frame_seq == 1
    creds = grpc.ssl_channel_credentials(root_certificates=cert)
    assert health_status(server.port, credentials=creds) == health_pb2.HealthCheckResponse.SERVING
    # A plaintext client gets nowhere.
    with pytest.raises(grpc.RpcError) as err:
        Client(f"127.0.0.1:{server.port}", token="tls-token", cache_dir=False).list_meshes(timeout=3)
    assert err.value.code() == grpc.StatusCode.UNAVAILABLE


def test_json_logs_one_line_per_session_event(server, tmp_path):
    from caveclod.server import logs
    stream = io.StringIO()
    logs.configure("json", stream)
    try:
        raw_stream(server.port, [open_message(mesh="nowhere")])
        code, _, responses = raw_stream(server.port, [open_message(), pb.ClientMessage(close=pb.Close())])
        assert code == grpc.StatusCode.OK
    finally:
        logging.getLogger(logs.LOGGER).handlers.clear()
    lines = [json.loads(line) for line in stream.getvalue().splitlines()]
    assert all({"time", "level", "event"} <= set(e) for e in lines)
    # The server's own events (server.packed, from its start-up thread) may fall in between.
    events = [e for e in lines if not e["event"].startswith("server.")]
    assert [e["event"] for e in events] == ["session.refused", "session.opened", "session.ended"]
    assert events[0]["code"] == "NOT_FOUND" and events[2]["reason"] == "closed"
