"""A LOD server: gRPC, health, reflection, metrics, the session reaper and drain.

``LodServer(config).start()`` answers health checks within a fraction of a
second: the meshes are memory-mapped (only headers are read) and the numba
kernels are loaded on a thread of their own afterwards; health says SERVING
at once, and an Open that arrives before the kernels are ready waits for
them.

The server model, chosen by measurement (docs/server.md):
grpc.aio on one event loop, which reads and writes every stream, and a pool
of worker threads, one per core, that make the frames (refinement releases
the GIL, so sessions refine in parallel). A thread per stream, the other
model measured, queued for the GIL once a few dozen streams were open.
The event loop runs on a thread of its own, so that this class keeps a
plain synchronous API (start, drain, stop) for ``caveclod serve`` and tests.
"""

from __future__ import annotations

import asyncio
import os
import threading
import time
from concurrent.futures import ThreadPoolExecutor

import grpc
import grpc.aio
from grpc_health.v1 import health, health_pb2, health_pb2_grpc
from grpc_reflection.v1alpha import reflection

from ..errors import CaveclodError
from . import logs
from .auth import BearerTokenInterceptor
from .config import H2_PLAINTEXT_ONLY, ServerConfig
from .meshes import Catalogue
from .metrics import Metrics
from .registry import Sessions
from .service import SERVICE, LodService, add_to_server

MiB = 1 << 20
# After a drain's grace (--drain-seconds), streams that are still open get
# this long to finish before the server stops. A supervisor's kill timeout
# (Kubernetes' terminationGracePeriodSeconds, compose's stop_grace_period)
# must exceed --drain-seconds plus this: tests/test_deploy_static.py checks
# that the deploy files do.
STOP_GRACE_SECONDS = 2.0
# Client messages are tiny (a pose is ~100 bytes): a larger one is refused.
MAX_RECEIVE = 64 * 1024


class LodServer:
    """One server process's gRPC server and everything it serves.

    Attributes:
        port: the port bound (useful with ``config.port == 0``).
        sessions: the :class:`.registry.Sessions` (tests reach the mirrors through it).
        metrics: the :class:`.metrics.Metrics`.
    """

    def __init__(self, config: ServerConfig):
        self.config = config
        self.catalogue = Catalogue(config.meshes, config.checked_dir)
        self.metrics = Metrics()
        self.sessions = Sessions(config, self.catalogue, self.metrics, logs.event)
        self.workers = ThreadPoolExecutor(max_workers=max(2, os.cpu_count() or 1), thread_name_prefix="caveclod-frame")
        self._loop = asyncio.new_event_loop()
        self._loop_thread = threading.Thread(target=self._loop.run_forever, daemon=True, name="caveclod-grpc")
        self._loop_thread.start()
        self._stop = threading.Event()
        self.metrics_port = None
        self.web_port = None
        self.web = None
        try:
            self.port = self._call(self._bind())
        except BaseException:
            self._close_loop()
            raise

    def _call(self, coroutine, timeout: float | None = None):
        """Run ``coroutine`` on the server's event loop and wait for its result."""
        return asyncio.run_coroutine_threadsafe(coroutine, self._loop).result(timeout)

    async def _bind(self) -> int:
        config = self.config
        interceptors = [BearerTokenInterceptor(config.tokens)] if config.tokens else []
        if config.transport == "h2" and config.tls_cert is not None:
            raise CaveclodError(H2_PLAINTEXT_ONLY)
        if config.transport == "h2":
            from .h2server import H2Server      # caveclod's own HTTP/2: the same services, less CPU a frame
            self.grpc = H2Server(interceptors, max_receive=MAX_RECEIVE, keepalive_seconds=config.keepalive_seconds,
                                 keepalive_timeout=config.keepalive_timeout, reuse_port=config.reuse_port)
        else:
            self.grpc = grpc.aio.server(interceptors=interceptors, options=grpc_options(config))
        service = LodService(self.sessions, self.catalogue, self.metrics, self.workers)
        add_to_server(service, self.grpc)
        self.health = health.aio.HealthServicer()
        health_pb2_grpc.add_HealthServicer_to_server(self.health, self.grpc)
        reflection.enable_server_reflection(
            (SERVICE, health_pb2.DESCRIPTOR.services_by_name["Health"].full_name, reflection.SERVICE_NAME),
            self.grpc)
        address = f"{config.host}:{config.port}"
        try:
            if config.tls_cert is not None:
                creds = grpc.ssl_server_credentials([(config.tls_key, config.tls_cert)])
                port = self.grpc.add_secure_port(address, creds)
            else:
                port = self.grpc.add_insecure_port(address)
        except RuntimeError:
            port = 0
        if not port:
            raise CaveclodError(f"cannot listen on {address}: the address is in use or not this machine's; "
                                "choose another --host/--port (--port 0 picks a free port)")
        if config.web_port is not None:
            from .web import WebFront           # aiohttp only where the viewer is asked for
            web_host = config.host if config.web_host is None else config.web_host
            self.web = WebFront(service, config)
            try:
                self.web_port = await self.web.start(web_host, config.web_port, config.reuse_port)
            except OSError as exc:
                raise CaveclodError(f"cannot listen on {web_host}:{config.web_port} for the viewer: "
                                    f"{exc.strerror}; choose another --web-host/--web-port (0 picks a free "
                                    "port)") from None
        return port

    def start(self) -> "LodServer":
        """Accept connections; health says SERVING; kernels load in the background."""
        self._call(self._start())
        if self.config.metrics_port is not None:
            self.metrics_port = self.metrics.serve(self.config.metrics_host, self.config.metrics_port)
        threading.Thread(target=self._warm_up, daemon=True, name="caveclod-warm-up").start()
        threading.Thread(target=self._reap, daemon=True, name="caveclod-reaper").start()
        logs.event("server.started", port=self.port, web_port=self.web_port, meshes=",".join(self.catalogue.names()),
                   max_sessions=self.config.max_sessions, tls=self.config.tls_cert is not None,
                   auth=bool(self.config.tokens))
        return self

    async def _start(self) -> None:
        await self.grpc.start()
        for name in ("", SERVICE):
            await self.health.set(name, health_pb2.HealthCheckResponse.SERVING)

    def _warm_up(self) -> None:
        """Load the refinement kernels (numba's cache), then admit Opens; then make what Opens
        would otherwise make: the default packed variant and the float32 payload's CRC."""
        t0 = time.perf_counter()
        try:
            from ..refine.view import View
            from .held import compile_encoders
            for served in self.catalogue.meshes.values():
                lo, hi = served.info.bounds_min, served.info.bounds_max
                # A small viewport: the update only has to run the kernels once. At 1280 x 720 this view
                # (a corner, looking across the whole mesh) refined a 47M-triangle rough terrain to 1.7M
                # faces, 3.5 s that every Open waited; at 64 x 36, 91,000 faces in 0.11 s.
                served.mesh.new_camera().update(View(eye=(hi.x, hi.y, hi.z + 1.0), target=(lo.x, lo.y, lo.z),
                                                     width=64, height=36))
            compile_encoders()
        except Exception as exc:              # a broken mesh must not hang every Open
            logs.event("server.warm_up_failed", error=repr(exc))
        finally:
            self.sessions.ready.set()
        logs.event("server.ready", seconds=round(time.perf_counter() - t0, 3))
        # The vertex buffer as most clients download it (packed at the default
        # bits), made now rather than by the first Open: at 17M vertices it
        # takes seconds, which the first session would otherwise wait.
        from ..vertexpack import DEFAULT_POSITION_BITS
        for served in self.catalogue.meshes.values():
            t1 = time.perf_counter()
            try:
                served.packed(DEFAULT_POSITION_BITS)
            except Exception as exc:
                logs.event("server.pack_failed", mesh=served.name, error=repr(exc))
                continue
            stored = (DEFAULT_POSITION_BITS, False) in served.stored
            logs.event("server.packed", mesh=served.name, position_bits=DEFAULT_POSITION_BITS, stored=stored,
                       seconds=round(time.perf_counter() - t1, 3),
                       **({} if stored else {"what_to_do": f"'caveclod pack {served.mesh.path}' stores it in the "
                                                            "file, so that a restart need not pack it"}))
        for served in self.catalogue.meshes.values():
            try:
                served.payload_crc32    # float32 downloads': reads the payload once (0.26 s at 16.8M vertices)
                # What OPS_LINKED sessions (caveclod loadtest's default) read: their
                # download packed with morph targets, and the targets' child ranks.
                served.packed(DEFAULT_POSITION_BITS, morph=True)
                served.op_links
            except Exception as exc:
                logs.event("server.warm_up_failed", mesh=served.name, error=repr(exc))

    def _reap(self) -> None:
        period = min(1.0, max(self.config.resume_ttl / 4, 0.05))
        while not self._stop.wait(period):
            self.sessions.reap()

    def drain(self, seconds: float | None = None) -> None:
        """Shut down gracefully: NOT_SERVING, refuse Opens, let sessions run ``seconds``, end them, stop.

        Returns early when every connected session has ended by itself.
        """
        seconds = self.config.drain_seconds if seconds is None else seconds
        self._call(self.health.enter_graceful_shutdown())     # every service NOT_SERVING, for good
        self.sessions.drain()
        attached, _ = self.sessions.counts()
        logs.event("server.draining", seconds=seconds, sessions=attached)
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline and self.sessions.counts()[0]:
            time.sleep(0.05)
        self.sessions.end_all()
        self.stop(grace=STOP_GRACE_SECONDS)
        logs.event("server.stopped")

    def stop(self, grace: float | None = None) -> None:
        """Stop at once (``grace`` seconds for RPCs in flight)."""
        if self._stop.is_set():
            return
        self._stop.set()
        self.sessions.end_all()
        try:
            if self.web is not None:
                self._call(self.web.stop())
            self._call(self.grpc.stop(grace))
        finally:
            self.metrics.stop()
            self.workers.shutdown(wait=False, cancel_futures=True)
            self._close_loop()

    def _close_loop(self) -> None:
        """Cancel the loop's tasks left over (a stream's reader that a client's cancel orphaned
        just before the stop: destroyed pending, asyncio would log it), stop the event loop's
        thread, then close the loop (its selector and wake-up pipe)."""
        async def cancel_the_rest():
            tasks = [t for t in asyncio.all_tasks() if t is not asyncio.current_task()]
            for t in tasks:
                t.cancel()
            if tasks:
                await asyncio.wait(tasks, timeout=2.0)

        if self._loop_thread.is_alive():
            try:
                asyncio.run_coroutine_threadsafe(cancel_the_rest(), self._loop).result(timeout=5.0)
            except (TimeoutError, RuntimeError):
                pass                      # a loop that cannot take it: stop it all the same
        self._loop.call_soon_threadsafe(self._loop.stop)
        self._loop_thread.join(5.0)
        if not self._loop_thread.is_alive():
            self._loop.close()


def grpc_options(config: ServerConfig) -> list:
    """Channel arguments: keepalive that reaps dead peers, small receive limit."""
    return [
        # Ping a connection idle for keepalive_seconds; drop it when the ping
        # is not answered in keepalive_timeout (a vanished peer, a network
        # cut). With this gRPC the unanswered ping is timed by
        # ping_timeout_ms (default: a minute), not by keepalive_timeout_ms
        # alone: set both. An idle session sends no data between frames, so
        # also lift the limits that stop pings without data (two pings, then
        # silence; five minutes between pings): tests/test_service_resilience.py
        # checks that a silently cut peer is reaped in seconds.
        ("grpc.keepalive_time_ms", int(1000 * config.keepalive_seconds)),
        ("grpc.keepalive_timeout_ms", int(1000 * config.keepalive_timeout)),
        ("grpc.http2.ping_timeout_ms", int(1000 * config.keepalive_timeout)),
        ("grpc.keepalive_permit_without_calls", 1),
        ("grpc.http2.max_pings_without_data", 0),
        ("grpc.http2.min_time_between_pings_ms", int(1000 * config.keepalive_seconds)),
        # Let clients keep their own keepalive pings every 10 s without being
        # told "too many pings".
        ("grpc.http2.min_recv_ping_interval_without_data_ms", 10_000),
        # No strikes: while the server compiles its kernels (a cold numba
        # cache: the first Open waits 1-2 minutes) gRPC answers pings late
        # and in bursts, and two strikes told a waiting client "too many
        # pings" (a fresh clone's make demo); our clients ping every 20 s.
        ("grpc.http2.max_ping_strikes", 0),
        # Client messages are tiny (a pose is ~100 bytes); frames are split
        # at 1 MiB of array data, so 4 MiB bounds a part with its framing.
        ("grpc.max_receive_message_length", MAX_RECEIVE),
        ("grpc.max_send_message_length", 4 * MiB),
        # Fail to bind a port that another process holds, instead of sharing
        # it, unless we are one of the processes of --processes N.
        ("grpc.so_reuseport", 1 if config.reuse_port else 0),
    ]
