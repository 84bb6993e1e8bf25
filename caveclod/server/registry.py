"""The sessions a server holds: Open and resume, the session limit, expiry, drain.

A session counts toward ``max_sessions`` from Open until it is closed,
refused, drained, or left detached (its stream broke) for ``resume_ttl``
seconds: a detached session still holds its cameras' memory.
"""

from __future__ import annotations

import secrets
import threading
import time

import grpc

from .. import vertexpack, wire
from ..errors import InputError, MeshDamagedError
from ..v1 import caveclod_pb2 as pb
from .config import MAX_ACK_WINDOW, ServerConfig
from .session import End, Refused, Session

MAX_BUDGET = (1 << 63) - 1

DRAINED = End(grpc.StatusCode.UNAVAILABLE,
              "the server is shutting down; open a new session, on another replica if there is one", True)
DRAINED_REFUSAL = Refused(DRAINED.code, DRAINED.message)


class Sessions:
    """Token -> Session, with the limits of ``config``.

    ``ready`` is set once the refinement kernels are loaded; Opens wait for
    it (the server answers health checks before that).
    """

    def __init__(self, config: ServerConfig, catalogue, metrics, log):
        self.config, self.catalogue, self.metrics, self.log = config, catalogue, metrics, log
        self.lock = threading.Lock()
        self.sessions: dict[str, Session] = {}
        self.draining = False
        self.ready = threading.Event()
        metrics.state_bytes.set_function(self.nbytes)

    # -- open / resume ---------------------------------------------------------------
    def open(self, msg: pb.Open) -> tuple[Session, int, bool]:
        """(session, stream generation, resumed) for an Open; raises Refused.

        A mesh a camera found damaged (its ``damaged`` set: while the server
        warmed up, or in another session) is refused with DATA_LOSS."""
        try:
            return self._open(msg)
        except MeshDamagedError:            # found damaged while this Open waited (cameras cannot be made of it)
            raise Refused(grpc.StatusCode.DATA_LOSS, damaged_message(self.catalogue.get(msg.mesh))) from None

    def _open(self, msg: pb.Open) -> tuple[Session, int, bool]:
        if self.draining:
            raise DRAINED_REFUSAL
        served = self.catalogue.get(msg.mesh)
        if served is None:
            # Echo a bounded name: a status's message travels in the client's metadata (16 KiB at most).
            name = msg.mesh if len(msg.mesh) <= 80 else msg.mesh[:80] + f"... ({len(msg.mesh)} characters)"
            raise Refused(grpc.StatusCode.NOT_FOUND, f"mesh {name!r} is not served here; this server serves "
                          f"{', '.join(self.catalogue.names())} (see ListMeshes)")
        if served.mesh.damaged:
            # A camera found the file damaged (caveclod.meshcheck's module doc): no new session on it.
            raise Refused(grpc.StatusCode.DATA_LOSS, damaged_message(served))
        view_options, budgets = self._options(msg.options)
        strict = msg.options.HasField("strict_bound") and msg.options.strict_bound
        cache = self._cache(msg, served)
        encoding = _frame_encoding(msg, cache)
        if encoding == pb.FRAME_ENCODING_OPS_LINKED:
            served.op_links                  # made here, outside the lock, if the warm-up has not yet
        try:
            vertexpack.requested_bits(msg)
        except ValueError as exc:
            raise Refused(grpc.StatusCode.INVALID_ARGUMENT, str(exc)) from None
        self.ready.wait()
        with self.lock:
            if self.draining:                # drained while this Open waited for the kernels
                raise DRAINED_REFUSAL
            old = self.sessions.get(msg.resume_token) if msg.resume_token else None
            if old is not None and self._expired(old, time.monotonic()):
                self._drop(old, "expired")
                old = None
            if old is not None:
                if old.served.name != msg.mesh or old.n_cameras != msg.cameras:
                    self._drop(old, "refused")
                    raise Refused(grpc.StatusCode.INVALID_ARGUMENT,
                                  f"resume of a session of mesh {old.served.name!r} with {old.n_cameras} cameras by an "
                                  f"Open of {msg.mesh!r} with {msg.cameras}; resume with the same mesh and cameras")
                if old.cache != cache:
                    self._drop(old, "refused")
                    raise Refused(grpc.StatusCode.INVALID_ARGUMENT,
                                  f"resume of a session with cache {_describe_cache(old.cache)} by an Open asking for "
                                  f"{_describe_cache(cache)}; resume with the same cache_vertices, cache_strategy and "
                                  "cache_pq_fraction")
                generation = old.attach(msg.last_frame_seq, view_options, frame_encoding=encoding)
                self._gauges()
                return old, generation, True
            if not 1 <= msg.cameras <= self.config.max_cameras:
                raise Refused(grpc.StatusCode.INVALID_ARGUMENT, f"Open.cameras is {msg.cameras}; this server takes "
                              f"1 to {self.config.max_cameras} cameras a session")
            if len(self.sessions) >= self.config.max_sessions:
                raise Refused(grpc.StatusCode.RESOURCE_EXHAUSTED,
                              f"the server holds its limit of {self.config.max_sessions} sessions; retry later with "
                              "backoff, or use another replica")
            window = msg.ack_window or self.config.ack_window
            session = Session(secrets.token_urlsafe(24), served, view_options, budgets, msg.cameras,
                              min(max(window, 1), MAX_ACK_WINDOW), self.config.settle_seconds, self.metrics,
                              client=msg.client[:80], cache=cache, frame_encoding=encoding, strict_bound=strict)
            self.sessions[session.token] = session
            generation = session.attach(0)
            self._gauges()
            return session, generation, False

    def _options(self, o: pb.RefineOptions) -> tuple[dict, tuple]:
        """(View keyword arguments, (max_ops, max_faces)) of Open.options, clamped to the server's caps."""
        from ..refine.view import View
        opts = wire.options_to_dict(o)
        view = {k: opts[k] if opts[k] is not None else wire.OPTION_DEFAULTS.get(k)
                for k in ("fov_y", "width", "height", "tolerance_px", "cull", "backface", "prune")}
        try:
            View(**view)
        except InputError as exc:
            raise Refused(grpc.StatusCode.INVALID_ARGUMENT, f"Open.options: {exc}") from None
        for key in ("max_ops", "max_faces"):
            if opts[key] is not None and opts[key] < 1:
                raise Refused(grpc.StatusCode.INVALID_ARGUMENT,
                              f"Open.options.{key} is 0; leave it unset for no budget, or give at least 1")
        # Budgets past int64 mean "no budget" in effect: clamp them, the kernels count in int64.
        max_ops, max_faces = (None if opts[k] is None else min(opts[k], MAX_BUDGET) for k in ("max_ops", "max_faces"))
        if self.config.max_ops is not None:
            max_ops = min(max_ops or self.config.max_ops, self.config.max_ops)
        if self.config.max_faces is not None:
            max_faces = min(max_faces or self.config.max_faces, self.config.max_faces)
        return view, (max_ops, max_faces)

    def _cache(self, msg: pb.Open, served) -> dict | None:
        """Open's cache mode checked: ``{vertices, strategy, pq_fraction}`` in use, or None (resident)."""
        from ..refine.vertexcache import check_options
        try:
            opts = wire.cache_options(msg)
        except wire.WireError as exc:
            raise Refused(grpc.StatusCode.INVALID_ARGUMENT, str(exc)) from None
        if opts is None:
            return None
        try:
            slots, strategy, pq = check_options(opts["vertices"], opts["strategy"] or "lru", opts["pq_fraction"])
        except InputError as exc:
            raise Refused(grpc.StatusCode.INVALID_ARGUMENT, f"Open: {exc}") from None
        slots = min(slots, served.mesh.n_vertices)           # more slots than vertices would never fill
        base = served.base_vertices
        if slots < base:
            raise Refused(grpc.StatusCode.INVALID_ARGUMENT,
                          f"Open.cache_vertices is {slots}, but the base mesh of {served.name!r} alone uses {base} "
                          f"vertices; ask for at least {base} slots (several times more keeps detail), or leave "
                          "cache_vertices unset for a resident vertex buffer")
        return {"vertices": slots, "strategy": strategy, "pq_fraction": pq}

    # -- ends ----------------------------------------------------------------------------
    def stream_ended(self, session: Session, generation: int, end: End) -> None:
        """Book-keeping once a stream of ``session`` is over."""
        with self.lock:
            if end.discard:
                self._drop(session, _why(end))
            else:
                current, own = session.detach(generation)
                if current and own is not None and own.discard:
                    # The stream broke after the session's own end was set (a Close read just before
                    # the browser's close frame, under load): that end, not the resume TTL. Before,
                    # such a session lingered, holding its place in --max-sessions, until the TTL.
                    self._drop(session, _why(own))
                elif current:
                    self.log("session.detached", **session.describe(), resume_ttl=self.config.resume_ttl)
            self._gauges()

    def _drop(self, session: Session, why: str) -> None:
        if self.sessions.pop(session.token, None) is not None:
            session.finish(End(grpc.StatusCode.ABORTED, "the session ended", True))
            self.metrics.session_ended(why)
            self.log("session.ended", **session.describe(), reason=why)

    def _expired(self, session: Session, now: float) -> bool:
        return not session.attached and now - session.detached_at > self.config.resume_ttl

    def reap(self) -> int:
        """Free detached sessions past the resume TTL; returns how many."""
        now = time.monotonic()
        with self.lock:
            gone = [s for s in self.sessions.values() if self._expired(s, now)]
            for s in gone:
                self._drop(s, "expired")
            self._gauges()
        return len(gone)

    def drain(self) -> None:
        """Refuse new Opens from now on (UNAVAILABLE)."""
        self.draining = True

    def end_all(self) -> None:
        """End every stream with UNAVAILABLE and forget every session."""
        with self.lock:
            for s in list(self.sessions.values()):
                s.finish(DRAINED)
                self._drop(s, "drained")
            self._gauges()

    def counts(self) -> tuple[int, int]:
        """(attached, detached) sessions."""
        attached = sum(1 for s in self.sessions.values() if s.attached)
        return attached, len(self.sessions) - attached

    def nbytes(self) -> int:
        """Bytes of every held session's camera states."""
        with self.lock:
            sessions = list(self.sessions.values())
        return sum(s.nbytes for s in sessions)

    def _gauges(self) -> None:
        self.metrics.set_sessions(*self.counts())



def damaged_message(served) -> str:
    """The one-line status message of a mesh a camera found damaged (no server path in it)."""
    return (f"mesh {served.name!r} is damaged ({served.mesh.damaged[:200]}); the server's operator must rebuild it "
            "with 'caveclod build' or copy it again")


def _describe_cache(cache: dict | None) -> str:
    if cache is None:
        return "none (a resident vertex buffer)"
    pq = f", pq_fraction {cache['pq_fraction']}" if cache["pq_fraction"] is not None else ""
    return f"{cache['vertices']} slots {cache['strategy']}{pq}"


def _frame_encoding(msg: pb.Open, cache: dict | None) -> int:
    """The frame encoding an Open gets: OPS_LINKED only where the client holds the
    morph targets (asked for, packed, outside cache mode, whose index buffers hold
    slot numbers), else OPS; an encoding this server does not know, RAW (the proto
    says so)."""
    asked = msg.frame_encoding
    if asked == pb.FRAME_ENCODING_OPS_LINKED:
        holds_targets = msg.morph_targets and msg.vertex_encoding == pb.VERTEX_ENCODING_PACKED and cache is None
        return pb.FRAME_ENCODING_OPS_LINKED if holds_targets else pb.FRAME_ENCODING_OPS
    return pb.FRAME_ENCODING_OPS if asked == pb.FRAME_ENCODING_OPS else pb.FRAME_ENCODING_RAW


def _why(end: End) -> str:
    """How a session ended with ``end``, as its session.ended log and metric name it."""
    return "closed" if end.code == grpc.StatusCode.OK else end.code.name.lower()
