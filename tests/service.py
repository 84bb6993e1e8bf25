"""Helpers of the service tests: in-process servers, `caveclod serve` processes,
raw streams that send any bytes, and a TCP proxy that can cut connections.

Every server listens on 127.0.0.1, port 0. Every process started here is
stopped by its pid in a ``finally``; every wait is bounded.
"""

from __future__ import annotations

import json
import os
import selectors
import signal
import socket
import subprocess
import sys
import threading
import time
from contextlib import contextmanager

import grpc

from caveclod.v1 import caveclod_pb2 as pb

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
WAIT = 20.0                     # seconds any single wait in these tests may take at most


def open_message(mesh="terrain", cameras=1, **options) -> pb.ClientMessage:
    """An Open with a 640x360 viewport unless ``options`` say otherwise."""
    opts = {"viewport_width": 640, "viewport_height": 360, **options}
    return pb.ClientMessage(open=pb.Open(mesh=mesh, cameras=cameras, options=pb.RefineOptions(**opts)))


def pose_message(camera, seq, eye, target, up=(0, 0, 1)) -> pb.ClientMessage:
    v = lambda p: pb.Vec3(x=p[0], y=p[1], z=p[2])       # noqa: E731
    return pb.ClientMessage(pose=pb.CameraPose(camera=camera, pose_seq=seq, eye=v(eye), target=v(target), up=v(up)))


def raw_stream(port: int, messages, timeout: float = WAIT, metadata=(), credentials=None):
    """Send ``messages`` (ClientMessages or raw bytes) on a Session stream, keep
    it open, and read until it ends. Returns (status code, details, responses).
    """
    target = f"127.0.0.1:{port}"
    channel = grpc.insecure_channel(target) if credentials is None else grpc.secure_channel(target, credentials)
    done = threading.Event()

    def requests():
        for m in messages:
            yield m if isinstance(m, bytes) else m.SerializeToString()
        done.wait(timeout)                  # keep our side open: a half-close would be a Close

    call = channel.stream_stream("/caveclod.v1.Lod/Session", request_serializer=lambda b: b,
                                 response_deserializer=pb.ServerMessage.FromString)(
        requests(), timeout=timeout, metadata=metadata)
    responses = []
    try:
        for r in call:
            responses.append(r)
        return grpc.StatusCode.OK, "", responses
    except grpc.RpcError as exc:
        return exc.code(), exc.details(), responses
    finally:
        done.set()
        channel.close()


def serve_process(*args, env=None):
    """Start `caveclod serve` on 127.0.0.1:0; returns (Popen, port) once it listens."""
    cmd = [sys.executable, "-m", "caveclod.cli", "serve", "--host", "127.0.0.1", "--port", "0", *args]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT,
                            env={**os.environ, **(env or {})})
    try:
        line = readline_within(proc.stdout, 60.0)
        if not line.startswith("listening on "):
            raise AssertionError(f"caveclod serve printed {line!r} first; stderr: {_stderr(proc)}")
        return proc, int(line.rsplit(":", 1)[1])
    except BaseException:
        stop_process(proc)
        raise


def readline_within(stream, seconds: float) -> str:
    """One line of ``stream``, or "" when none arrives within ``seconds``.

    A selector rather than select.select: select() refuses descriptors above
    1023, which a long test session can reach.
    """
    with selectors.DefaultSelector() as sel:
        sel.register(stream, selectors.EVENT_READ)
        return stream.readline() if sel.select(seconds) else ""


def _stderr(proc) -> str:
    stop_process(proc)
    return proc.stderr.read()[-2000:]


def stop_process(proc, sig=signal.SIGKILL, timeout: float = WAIT) -> int | None:
    """Send ``sig`` to ``proc`` (by its pid) and wait for it; returns its exit status."""
    if proc.poll() is None:
        try:
            os.kill(proc.pid, sig)
        except ProcessLookupError:
            pass
    try:
        return proc.wait(timeout)
    except subprocess.TimeoutExpired:
        os.kill(proc.pid, signal.SIGKILL)
        return proc.wait(timeout)


def log_events(lines, name: str) -> list[dict]:
    """The JSON log lines (``--log-format json``) of event ``name``, parsed; other lines skipped."""
    out = []
    for line in lines:
        try:
            event = json.loads(line)
        except ValueError:
            continue
        if isinstance(event, dict) and event.get("event") == name:
            out.append(event)
    return out


def wait_until(predicate, timeout: float = WAIT, step: float = 0.02) -> bool:
    """Poll ``predicate`` until it is true or ``timeout`` passes; returns its last value."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(step)
    return bool(predicate())


class Proxy:
    """A TCP proxy on 127.0.0.1 whose connections ``cut()`` breaks (a network cut, seen from both ends)."""

    def __init__(self, port: int):
        self.target = port
        self.listener = socket.create_server(("127.0.0.1", 0))
        self.port = self.listener.getsockname()[1]
        self.lock = threading.Lock()
        self.sockets: list[socket.socket] = []
        self.closed = False
        self.frozen = False           # drop every byte, close nothing: a silent network cut
        threading.Thread(target=self._accept, daemon=True).start()

    def _accept(self) -> None:
        while not self.closed:
            try:
                client, _ = self.listener.accept()
            except OSError:
                return
            try:
                upstream = socket.create_connection(("127.0.0.1", self.target))
            except OSError:
                client.close()
                continue
            with self.lock:
                self.sockets += [client, upstream]
            for a, b in ((client, upstream), (upstream, client)):
                threading.Thread(target=self._pipe, args=(a, b), daemon=True).start()

    def _pipe(self, src: socket.socket, dst: socket.socket) -> None:
        try:
            while data := src.recv(65536):
                if not self.frozen:
                    dst.sendall(data)
        except OSError:
            pass
        finally:
            for s in (src, dst):
                try:
                    s.shutdown(socket.SHUT_RDWR)
                except OSError:
                    pass

    def cut(self) -> None:
        """Break every connection through the proxy; new ones are still accepted."""
        with self.lock:
            for s in self.sockets:
                try:
                    s.shutdown(socket.SHUT_RDWR)
                except OSError:
                    pass
                s.close()
            self.sockets.clear()

    def close(self) -> None:
        self.closed = True
        self.listener.close()
        self.cut()


@contextmanager
def proxy_to(port: int):
    p = Proxy(port)
    try:
        yield p
    finally:
        p.close()


class Driver:
    """Drives a :class:`caveclod.client.SessionProtocol` over a raw stream, acking only when told.

    With ``ack_window=1`` the server cannot make frame N+1 before the ack
    of frame N, so a test can compare the client's buffers with the server's
    mirror between the two.
    """

    def __init__(self, port: int, protocol, timeout: float = 120.0, metadata=()):
        import queue
        self.protocol = protocol
        self.requests: queue.Queue = queue.Queue()
        self.responses: queue.Queue = queue.Queue()
        self.channel = grpc.insecure_channel(f"127.0.0.1:{port}")
        self.requests.put(protocol.open_message())
        call = self.channel.stream_stream("/caveclod.v1.Lod/Session", request_serializer=pb.ClientMessage.SerializeToString,
                                          response_deserializer=pb.ServerMessage.FromString)
        self.call = call(iter(self.requests.get, None), timeout=timeout, metadata=metadata)
        self.held: list = []              # acks not sent yet
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self) -> None:
        try:
            for msg in self.call:
                self.responses.put(msg)
            self.responses.put(None)
        except grpc.RpcError as exc:
            self.responses.put(exc)

    def send(self, msg) -> None:
        self.requests.put(msg)

    def pose(self, camera, eye, target, up=(0, 0, 1)) -> int:
        msg = self.protocol.pose_message(camera, eye, target, up)
        self.send(msg)
        return msg.pose.pose_seq

    def next_frame(self, timeout: float = WAIT, ack: bool = True):
        """The next complete frame (a FrameUpdate), or None after ``timeout``; raises on a status."""
        import queue
        deadline = time.monotonic() + timeout
        while True:
            try:
                item = self.responses.get(timeout=max(deadline - time.monotonic(), 0.0))
            except queue.Empty:
                return None
            if item is None or isinstance(item, grpc.RpcError):
                raise AssertionError(f"the stream ended: {item and (item.code(), item.details())}")
            out, update = self.protocol.receive(item)
            for m in out:
                if m.WhichOneof("kind") == "ack":
                    self.held.append(m)
                else:
                    self.send(m)
            if update is not None:
                if ack:
                    self.ack()
                return update

    def ack(self) -> None:
        for m in self.held:
            self.send(m)
        self.held.clear()

    def close(self) -> None:
        self.requests.put(None)
        self.call.cancel()
        self.channel.close()
