"""Prometheus metrics of a LOD server (prometheus-client), served on ``--metrics-port``.

Each server has a registry of its own, so that several servers in one
process (the tests) do not share counters.
"""

from __future__ import annotations

from prometheus_client import CollectorRegistry, Counter, Gauge, Histogram, start_http_server

from ..v1 import caveclod_pb2 as pb

# Refinement and latency buckets, seconds: a camera update takes about a
# millisecond; pose -> frame latency targets are tens of milliseconds.
REFINE_BUCKETS = (0.0005, 0.001, 0.002, 0.004, 0.008, 0.016, 0.032, 0.064, 0.128, 0.5, 2.0)
LATENCY_BUCKETS = (0.002, 0.005, 0.01, 0.02, 0.03, 0.05, 0.075, 0.1, 0.2, 0.5, 1.0, 5.0)


class Metrics:
    """The counters, gauges and histograms, and the hooks sessions call."""

    def __init__(self):
        self.registry = r = CollectorRegistry()
        self.sessions_active = Gauge("caveclod_sessions_active", "Sessions with a connected stream", registry=r)
        self.sessions_resumable = Gauge("caveclod_sessions_resumable",
                                        "Sessions whose stream broke, resumable until the resume TTL", registry=r)
        self.frames = Counter("caveclod_frames_total", "Frames sent (a frame of several parts counts once)",
                              registry=r)
        self.bytes_sent = Counter("caveclod_bytes_sent_total",
                                  "Serialized bytes of ServerMessages sent on Session streams", registry=r)
        self.operations = Counter("caveclod_refine_operations_total", "Vertex splits and edge collapses made",
                                  registry=r)
        self.refine_cpu = Counter("caveclod_refine_cpu_seconds_total",
                                  "CPU time of the threads refining cameras, in updates (its rate: cores used)",
                                  registry=r)
        self.refine_seconds = Histogram("caveclod_refine_seconds", "Time of one camera update",
                                        buckets=REFINE_BUCKETS, registry=r)
        self.pose_to_frame = Histogram("caveclod_pose_to_frame_seconds",
                                       "From a pose's arrival to the frame answering it", buckets=LATENCY_BUCKETS,
                                       registry=r)
        self.state_bytes = Gauge("caveclod_camera_state_bytes",
                                 "Bytes of the refinement states of every camera held (the meshes not counted)",
                                 registry=r)
        self.keyframe_requests = Counter("caveclod_keyframe_requests_total", "KeyframeRequests by reason",
                                         ["reason"], registry=r)
        self.session_ends = Counter("caveclod_session_ends_total",
                                    "Sessions ended, by reason (closed, expired, drained, a status code)",
                                    ["reason"], registry=r)
        self.cache_inserts = Counter("caveclod_cache_vertices_inserted_total",
                                     "Cache mode: vertices written into clients' slots (misses; keyframes not counted)",
                                     registry=r)
        self.cache_hits = Counter("caveclod_cache_hits_total",
                                  "Cache mode: vertices that became active while still in a client's slot",
                                  registry=r)
        self._http = None

    def serve(self, host: str, port: int) -> int:
        """Start the /metrics HTTP exporter; returns its port."""
        self._http, _ = start_http_server(port, addr=host, registry=self.registry)
        return self._http.server_port

    def stop(self) -> None:
        if self._http is not None:
            self._http.shutdown()
            self._http = None

    # -- hooks ----------------------------------------------------------------------------
    def set_sessions(self, attached: int, detached: int) -> None:
        self.sessions_active.set(attached)
        self.sessions_resumable.set(detached)

    def refined(self, seconds: float, operations: int, cpu_seconds: float) -> None:
        self.refine_seconds.observe(seconds)
        self.operations.inc(operations)
        self.refine_cpu.inc(cpu_seconds)

    def cached(self, inserted: int, hits: int) -> None:
        self.cache_inserts.inc(inserted)
        self.cache_hits.inc(hits)

    def pose_answered(self, seconds: float) -> None:
        self.pose_to_frame.observe(seconds)

    def frame_sent(self, nbytes: int) -> None:
        self.frames.inc()
        self.bytes_sent.inc(nbytes)

    def bytes_out(self, nbytes: int) -> None:
        self.bytes_sent.inc(nbytes)

    def keyframe_requested(self, reason: int) -> None:
        name = pb.KeyframeReason.Name(reason) if reason in pb.KeyframeReason.values() else str(reason)
        self.keyframe_requests.labels(name.removeprefix("KEYFRAME_REASON_").lower()).inc()

    def session_ended(self, reason: str) -> None:
        self.session_ends.labels(reason).inc()
