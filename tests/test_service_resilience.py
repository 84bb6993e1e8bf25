"""Broken connections, slow readers, killed clients and shutdown."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
import urllib.request

import grpc
import numpy as np
import pytest

from caveclod.v1 import caveclod_pb2 as pb

from service import ROOT, open_message, pose_message, proxy_to, raw_stream, serve_process, stop_process, wait_until


def _mirror_equals(server, session) -> bool:
    mirror = server.sessions.sessions[session.protocol.token]
    return all(
        sorted(session.triangles(c)) == sorted(mirror.cams[c].triangles())
        and all(np.array_equal(session.triangles(c)[m], t) for m, t in mirror.cams[c].triangles().items())
        for c in range(mirror.n_cameras))


def test_a_dropped_connection_is_resumed_with_the_token(server, tmp_path):
    from caveclod.client import Client
    from caveclod.paths import circle
    with proxy_to(server.port) as proxy, Client(f"127.0.0.1:{proxy.port}", cache_dir=tmp_path) as client:
        with client.session("terrain", cameras=2, width=640, height=360) as s:
            lo, hi = s.vertex_buffer.positions.min(0), s.vertex_buffer.positions.max(0)
            token = s.protocol.token
            last = 0
            for i in range(60):
                for c in range(2):
                    s.send_pose(c, *circle(lo, hi, c, i))
                if i == 30:
                    proxy.cut()              # the network breaks under the stream
                frame = s.next_frame(timeout=10)
                while frame is None:
                    frame = s.next_frame(timeout=10)
                assert frame.frame_seq > last
                last = frame.frame_seq
            while s.next_frame(timeout=0.5) is not None:
                pass
            assert s.protocol.resumes == 1 and s.protocol.token == token
            assert s.info.resumed
            assert s.protocol.divergences == 0
            assert list(server.sessions.sessions) == [token]
            assert _mirror_equals(server, s)


def test_keepalive_reaps_a_peer_behind_a_silent_network_cut(make_server, tmp_path):
    """No FIN, no RST: only the server's keepalive pings find out that the peer is gone."""
    server = make_server(keepalive_seconds=0.5, keepalive_timeout=0.5, resume_ttl=0)
    from caveclod.client import Client
    with proxy_to(server.port) as proxy:
        client = Client(f"127.0.0.1:{proxy.port}", cache_dir=tmp_path)
        try:
            s = client.session("terrain", width=640, height=360, retries=0)
            assert s.next_frame(timeout=10).frame_seq == 1
            assert server.sessions.counts() == (1, 0)
            proxy.frozen = True
            assert wait_until(lambda: not server.sessions.sessions, timeout=15), "the dead peer was not reaped"
        finally:
            client.close()


def test_a_resume_takes_the_session_from_the_old_stream(server):
    results = {}

    def first():
        results["first"] = raw_stream(server.port, [open_message()], timeout=10)

    thread = threading.Thread(target=first)
    thread.start()
    assert wait_until(lambda: server.sessions.sessions and next(iter(server.sessions.sessions.values())).frame_seq)
    token = next(iter(server.sessions.sessions))
    resume = open_message()
    resume.open.resume_token = token
    resume.open.last_frame_seq = 0                 # "I applied nothing": a keyframe follows
    code, _, responses = raw_stream(server.port, [resume], timeout=1.5)
    thread.join(20)
    assert results["first"][0] == grpc.StatusCode.ABORTED
    info = responses[0].session_info
    assert info.resumed and info.session_token == token and info.last_frame_seq == 1
    assert info.vertex_buffer_cached is False
    frames = [r.frame for r in responses if r.WhichOneof("kind") == "frame"]
    assert frames[0].frame_seq == 2 and frames[0].cameras[0].keyframe


def test_an_expired_token_starts_a_fresh_session(make_server):
    server = make_server(resume_ttl=0)
    code, _, responses = raw_stream(server.port, [open_message()], timeout=1.0)
    token = responses[0].session_info.session_token
    assert wait_until(lambda: token not in server.sessions.sessions, timeout=5)
    resume = open_message()
    resume.open.resume_token = token
    _, _, responses = raw_stream(server.port, [resume], timeout=1.0)
    info = responses[0].session_info
    assert not info.resumed and info.session_token != token


def test_a_slow_reader_costs_bounded_memory_while_another_session_keeps_its_latency(server, tmp_path):
    """A client that never acks: the server makes ack_window frames and then nothing, however many poses."""
    from caveclod.client import Client
    from caveclod.paths import flyover
    lo, hi = np.array([0.0, 0.0, 0.0]), np.array([47.0, 47.0, 10.0])
    n_poses = 600
    poses = [pose_message(0, i + 1, *flyover(lo, hi, 0, i / 30)[:2]) for i in range(n_poses)]
    slow = {}

    def never_acks():
        slow["result"] = raw_stream(server.port, [open_message(), *poses], timeout=4.0)

    thread = threading.Thread(target=never_acks)
    thread.start()
    latencies = []
    try:
        with Client(f"127.0.0.1:{server.port}", cache_dir=tmp_path) as client:
            with client.session("terrain", width=640, height=360) as s:
                for i in range(60):
                    s.send_pose(0, *flyover(lo, hi, 1, i / 30))
                    while (f := s.next_frame(timeout=2)) is not None:
                        if 0 in f.cameras and f.cameras[0].latency is not None:
                            latencies.append(f.cameras[0].latency)
                            break
                    time.sleep(1 / 60)
                assert s.protocol.divergences == 0
                slow_session = next(x for x in server.sessions.sessions.values() if x.token != s.protocol.token)
                assert slow_session.last_pose_seq == n_poses         # every pose was read ...
                assert slow_session.frame_seq == slow_session.ack_window == 4   # ... but only 4 frames made
                assert all(p is None for p in slow_session.pending) or slow_session.pending[0].seq == n_poses
    finally:
        thread.join(20)
    frames = [r for r in slow["result"][2] if r.WhichOneof("kind") == "frame"]
    assert len(frames) == 4
    assert len(latencies) == 60
    # A session stuck behind the slow one would wait seconds; this machine is shared, so allow noise.
    assert np.percentile(latencies, 99) < 0.25, f"p99 {np.percentile(latencies, 99) * 1e3:.1f} ms"


CLIENT = """
import sys
from caveclod.client import Client
with Client(sys.argv[1], cache_dir=False) as client:
    s = client.session("terrain", cameras=2, width=640, height=360)
    s.send_pose(0, (0, 0, 60), (20, 20, 0))
    s.next_frame(timeout=10)
    print("ready", flush=True)
    sys.stdin.read()
"""


def _metrics(port) -> dict:
    text = urllib.request.urlopen(f"http://127.0.0.1:{port}/metrics", timeout=10).read().decode()
    return {line.split(" ")[0]: float(line.split(" ")[1]) for line in text.splitlines()
            if line and not line.startswith("#")}


def _threads(pid: int) -> int:
    with open(f"/proc/{pid}/status") as fh:
        return int(next(line for line in fh if line.startswith("Threads:")).split()[1])


def _rss(pid: int) -> int:
    with open(f"/proc/{pid}/status") as fh:
        return int(next(line for line in fh if line.startswith("VmRSS:")).split()[1]) * 1024


@pytest.mark.skipif(not os.path.exists("/proc/self/status"), reason="reads thread counts from /proc")
def test_killed_clients_are_freed_after_the_resume_ttl(terrain_path):
    """Two rounds of three clients killed mid-session: after each, the sessions
    expire, and the second round leaves the server as the first did (idle pool
    threads are kept for reuse; nothing accumulates)."""
    server, port = serve_process(str(terrain_path), "--resume-ttl", "1", "--metrics-port", "0",
                                 "--metrics-host", "127.0.0.1", "--log-format", "json")
    clients = []
    try:
        line = server.stderr.readline()
        while '"server.metrics"' not in line:
            line = server.stderr.readline()
        metrics_port = int(line.split('"port": ')[1].split("}")[0])
        after = []
        for round_ in range(2):
            clients = [subprocess.Popen([sys.executable, "-c", CLIENT, f"127.0.0.1:{port}"], stdin=subprocess.PIPE,
                                        stdout=subprocess.PIPE, text=True, cwd=ROOT) for _ in range(3)]
            for proc in clients:
                assert proc.stdout.readline().strip() == "ready"
            m = _metrics(metrics_port)
            assert m["caveclod_sessions_active"] == 3 and m["caveclod_camera_state_bytes"] > 0
            for proc in clients:
                stop_process(proc, signal.SIGKILL)
            assert wait_until(lambda: _metrics(metrics_port)["caveclod_sessions_active"] == 0, timeout=10)
            assert wait_until(lambda: _metrics(metrics_port)["caveclod_sessions_resumable"] == 0, timeout=10)
            m = _metrics(metrics_port)
            assert m["caveclod_camera_state_bytes"] == 0
            assert m['caveclod_session_ends_total{reason="expired"}'] == 3 * (round_ + 1), {k: v for k, v in m.items() if "ends" in k}
            time.sleep(0.5)                         # reader threads see their streams end
            after.append((_threads(server.pid), _rss(server.pid)))
        (threads1, rss1), (threads2, rss2) = after
        assert threads2 <= threads1, f"threads grew from {threads1} to {threads2}"
        assert rss2 < rss1 + (8 << 20), f"memory grew from {rss1 >> 20} MiB to {rss2 >> 20} MiB"
    finally:
        for proc in clients:
            stop_process(proc)
        stop_process(server)


@pytest.mark.parametrize("transport", ["grpc", "h2"])
def test_sigterm_drains_then_exits_0(terrain_path, transport):
    from caveclod.client import SessionProtocol
    from service import Driver
    server, port = serve_process(str(terrain_path), "--drain-seconds", "2", "--transport", transport)
    driver = None
    try:
        options = {"width": 640, "height": 360}
        driver = Driver(port, SessionProtocol("terrain", 1, options), timeout=30)
        assert driver.next_frame().frame_seq == 1          # the session is open
        t0 = time.monotonic()
        os.kill(server.pid, signal.SIGTERM)
        from grpc_health.v1 import health_pb2, health_pb2_grpc
        with grpc.insecure_channel(f"127.0.0.1:{port}") as channel:
            stub = health_pb2_grpc.HealthStub(channel)
            assert wait_until(lambda: stub.Check(health_pb2.HealthCheckRequest(), timeout=5).status
                              == health_pb2.HealthCheckResponse.NOT_SERVING, timeout=5)
        code, details, _ = raw_stream(port, [open_message()])
        assert code == grpc.StatusCode.UNAVAILABLE
        driver.pose(0, (0, 0, 60), (20, 20, 0))            # the open session still works while draining
        assert driver.next_frame().cameras[0].pose_seq == 1
        end = driver.responses.get(timeout=20)
        while isinstance(end, pb.ServerMessage):
            end = driver.responses.get(timeout=20)
        assert isinstance(end, grpc.RpcError), end
        assert end.code() == grpc.StatusCode.UNAVAILABLE and "shutting down" in end.details()
        assert 1.5 < time.monotonic() - t0 < 6.0        # the session ran on for --drain-seconds
        assert server.wait(20) == 0
        assert "server.stopped" in server.stderr.read()
    finally:
        if driver is not None:
            driver.close()
        stop_process(server)


def test_serve_prints_the_listening_line_first_and_refuses_bad_options(terrain_path, tmp_path):
    server, port = serve_process(str(terrain_path))
    try:
        assert port > 0
    finally:
        assert stop_process(server, signal.SIGINT) == 0            # SIGINT drains too
    for args, words in ((["--tls-cert", str(terrain_path)], "--tls-key"),
                        (["--token-file", str(tmp_path / "none")], "--token-file"),
                        (["--max-sessions", "0"], "--max-sessions"),
                        (["--transport", "h2", "--tls-cert", str(terrain_path), "--tls-key", str(terrain_path)],
                         "plaintext only"),
                        ([], "no such file")):
        mesh = [str(tmp_path / "missing.cvc")] if not args else [str(terrain_path)]
        proc = subprocess.run([sys.executable, "-m", "caveclod.cli", "serve", *mesh, "--port", "0", *args],
                              capture_output=True, text=True, cwd=ROOT, timeout=60)
        assert proc.returncode == 2, proc.stderr
        assert words in proc.stderr and proc.stderr.count("\n") == 1 and "Traceback" not in proc.stderr
