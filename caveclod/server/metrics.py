"""Prometheus metrics of a LOD server (prometheus-client), served on ``--metrics-port``.

Each server has a registry of its own, so that several servers in one
process (the tests) do not share counters.

What changes every frame (frames, bytes, operations, refinement CPU, the
update-time and latency histograms) is kept in plain per-thread tallies
(:class:`Tally`: numbers and lists, no lock) and read by a collector when
Prometheus scrapes: a prometheus-client Counter or Histogram takes a lock
per call, about 14 us a frame in all. Each thread adds only to its own
tally, so no increment is lost; a scrape sums them. Rare events (keyframe
requests, session ends) stay prometheus-client Counters.
"""

from __future__ import annotations

import bisect
import threading

from prometheus_client import CollectorRegistry, Counter, Gauge, start_http_server
from prometheus_client.core import CounterMetricFamily, HistogramMetricFamily

from ..v1 import caveclod_pb2 as pb

# Refinement and latency buckets, seconds: a camera update takes about a
# millisecond; pose -> frame latency targets are tens of milliseconds.
REFINE_BUCKETS = (0.0005, 0.001, 0.002, 0.004, 0.008, 0.016, 0.032, 0.064, 0.128, 0.5, 2.0)
LATENCY_BUCKETS = (0.002, 0.005, 0.01, 0.02, 0.03, 0.05, 0.075, 0.1, 0.2, 0.5, 1.0, 5.0)
# KeyframeRequest reasons a client may send that get a label of their own;
# any other number counts as "other" (a client must not grow the series).
KEYFRAME_REASONS = {v: pb.KeyframeReason.Name(v).removeprefix("KEYFRAME_REASON_").lower()
                    for v in pb.KeyframeReason.values()}

_COUNTERS = (
    ("frames", "caveclod_frames", "Frames sent (a frame of several parts counts once)"),
    ("bytes_sent", "caveclod_bytes_sent", "Serialized bytes of ServerMessages sent on Session streams"),
    ("operations", "caveclod_refine_operations", "Vertex splits and edge collapses made"),
    ("refine_cpu", "caveclod_refine_cpu_seconds",
     "CPU time of the threads refining cameras, in updates (its rate: cores used)"),
    ("cache_inserts", "caveclod_cache_vertices_inserted",
     "Cache mode: vertices written into clients' slots (misses; keyframes not counted)"),
    ("cache_hits", "caveclod_cache_hits", "Cache mode: vertices that became active while still in a client's slot"),
)
_HISTOGRAMS = (
    ("refine_seconds", "caveclod_refine_seconds", "Time of one camera update", REFINE_BUCKETS),
    ("pose_to_frame", "caveclod_pose_to_frame_seconds", "From a pose's arrival to the frame answering it",
     LATENCY_BUCKETS),
)


class Tally:
    """One thread's share of the per-frame metrics: plain numbers, added to without a lock."""

    def __init__(self):
        for name, _, _ in _COUNTERS:
            setattr(self, name, 0.0)
        for name, _, _, buckets in _HISTOGRAMS:
            setattr(self, name, [0] * (len(buckets) + 1))     # per bucket (not cumulative), +Inf last
            setattr(self, name + "_sum", 0.0)


class _FrameCollector:
    """Exports the sum of every thread's Tally at scrape time."""

    def __init__(self, metrics: "Metrics"):
        self.metrics = metrics

    def collect(self):
        tallies = self.metrics.tallies()
        for name, metric, doc in _COUNTERS:
            family = CounterMetricFamily(metric, doc)
            family.add_metric([], sum(getattr(t, name) for t in tallies))
            yield family
        for name, metric, doc, buckets in _HISTOGRAMS:
            counts = [sum(c) for c in zip(*(getattr(t, name) for t in tallies))] or [0] * (len(buckets) + 1)
            cumulative, total = [], 0
            for edge, c in zip((*(str(b) for b in buckets), "+Inf"), counts):
                total += c
                cumulative.append((edge, total))
            yield HistogramMetricFamily(metric, doc, buckets=cumulative,
                                        sum_value=sum(getattr(t, name + "_sum") for t in tallies))


class Metrics:
    """The counters, gauges and histograms, and the hooks sessions call."""

    def __init__(self):
        self.registry = r = CollectorRegistry()
        self.sessions_active = Gauge("caveclod_sessions_active", "Sessions with a connected stream", registry=r)
        self.sessions_resumable = Gauge("caveclod_sessions_resumable",
                                        "Sessions whose stream broke, resumable until the resume TTL", registry=r)
        self.state_bytes = Gauge("caveclod_camera_state_bytes",
                                 "Bytes of the refinement states of every camera held (the meshes not counted)",
                                 registry=r)
        self.keyframe_requests = Counter("caveclod_keyframe_requests_total", "KeyframeRequests by reason",
                                         ["reason"], registry=r)
        self.session_ends = Counter("caveclod_session_ends_total",
                                    "Sessions ended, by reason (closed, expired, drained, a status code)",
                                    ["reason"], registry=r)
        self._local = threading.local()
        self._tallies: list[Tally] = []
        self._lock = threading.Lock()          # only to register a new thread's tally
        r.register(_FrameCollector(self))
        self._http = None

    def _tally(self) -> Tally:
        """This thread's Tally (made on its first use)."""
        try:
            return self._local.tally
        except AttributeError:
            t = self._local.tally = Tally()
            with self._lock:
                self._tallies.append(t)
            return t

    def tallies(self) -> list:
        with self._lock:
            return list(self._tallies)

    def total(self, name: str) -> float:
        """A per-frame counter summed over threads (``frames``, ``bytes_sent``, ``refine_cpu`` ...)."""
        return sum(getattr(t, name) for t in self.tallies())

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
        t = self._tally()
        t.refine_seconds[bisect.bisect_left(REFINE_BUCKETS, seconds)] += 1
        t.refine_seconds_sum += seconds
        t.operations += operations
        t.refine_cpu += cpu_seconds

    def cached(self, inserted: int, hits: int) -> None:
        t = self._tally()
        t.cache_inserts += inserted
        t.cache_hits += hits

    def pose_answered(self, seconds: float) -> None:
        t = self._tally()
        t.pose_to_frame[bisect.bisect_left(LATENCY_BUCKETS, seconds)] += 1
        t.pose_to_frame_sum += seconds

    def frame_sent(self, nbytes: int) -> None:
        t = self._tally()
        t.frames += 1
        t.bytes_sent += nbytes

    def bytes_out(self, nbytes: int) -> None:
        self._tally().bytes_sent += nbytes

    def keyframe_requested(self, reason: int) -> None:
        self.keyframe_requests.labels(KEYFRAME_REASONS.get(reason, "other")).inc()

    def session_ended(self, reason: str) -> None:
        self.session_ends.labels(reason).inc()
