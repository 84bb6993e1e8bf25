"""One session: its cameras' refinement states and the rules of caveclod.v1.

A session outlives its streams (resume). While a stream is attached, its
reader (``accept``: poses, acks, keyframe requests, close; quick, under
``cond``) runs on the server's event loop, and its writer asks ``poll``
whether a frame is due; when one is, ``make_frame`` refines every camera
that has work and encodes the frame on a worker thread. Refinement runs
outside ``cond``, so poses keep arriving meanwhile, and under ``writer``, so
a resume waits for a frame in progress to finish before it decides whether
the client lost frames. Every change a writer may be waiting for calls the
session's *wakers* (thread-safe callbacks the writers register).

The per-pose rules (all in the proto's ``Lod.Session`` comment): latest pose
wins; at most one update per camera per frame; a camera whose last update
made operations is updated again for the same pose, after ``settle``
seconds (at once when a budget stopped it), until an update makes none.

Cache mode (Open.cache_vertices): each camera is a
:class:`~caveclod.refine.cachedcamera.CachedCamera`, the exact mirror of the
client's slots; a frame carries its vertex writes (attributes read from the
mapped vertex buffer) and index writes in slot numbers, with the slots
checksum kept up to date per written slot.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass

import grpc
import numpy as np

from .. import wire
from ..checksums import SlotChecksum
from ..errors import InputError
from ..refine.view import View, view_params
from .held import HeldBuffers
from ..v1 import caveclod_pb2 as pb


# Frames using less CPU than this (recent average) are made on the event loop;
# longer ones on a worker, where they refine in parallel but their Python
# contends with the loop for the GIL. Measured at 64 sessions on 2 cores, p99
# pose -> frame: 0.3 ms, 73 ms (the loop waiting on workers' GIL); 1 ms, 32-35
# ms; 2 ms, 59 ms (a jump's 1-2 ms updates holding every stream up in turn).
CHEAP_SECONDS = 0.001


class Refused(Exception):
    """Ends a stream with ``code`` and a one-line ``message``."""

    def __init__(self, code: grpc.StatusCode, message: str):
        super().__init__(message)
        self.code, self.message = code, message


@dataclass
class End:
    """Why a stream ends: a status code (OK for a Close) and its message."""

    code: grpc.StatusCode
    message: str
    discard: bool            # the session ends too (False: it stays resumable)


CLOSED = End(grpc.StatusCode.OK, "", True)


@dataclass
class _Pose:
    seq: int
    eye: tuple               # checked (caveclod.refine.view.check_pose); the View is made
    target: tuple            # only if this pose is refined for, as newer ones often
    up: tuple                # replace a pose first
    received: float          # time.monotonic() when it arrived


class Session:
    """A set of cameras refining one mesh, and the ack window, poses and keyframes.

    Args:
        token: the session token.
        served: the ServedMesh.
        view_options: View keyword arguments (fov_y, width, height,
            tolerance_px, cull, backface), already validated.
        budgets: (max_ops, max_faces), None meaning unlimited.
        cameras: number of cameras.
        ack_window: frames in flight before an ack.
        settle: seconds before a convergence update.
        hooks: the server's metrics (see :mod:`.metrics`).
        cache: cache mode ``{vertices, strategy, pq_fraction}`` (checked:
            :meth:`.registry.Sessions._cache`), or None for a resident
            vertex buffer. Each camera has a cache of its own.
        frame_encoding: FRAME_ENCODING_RAW, _OPS or _OPS_LINKED (already
            granted: :meth:`.registry.Sessions.open` decides).
        strict_bound: the cameras' strict error bound
            (:class:`caveclod.refine.camera.CameraState`); kept when resumed.
    """

    def __init__(self, token: str, served, view_options: dict, budgets: tuple, cameras: int, ack_window: int,
                 settle: float, hooks, client: str = "", cache: dict | None = None,
                 frame_encoding: int = pb.FRAME_ENCODING_RAW, strict_bound: bool = False):
        self.token, self.served, self.client = token, served, client
        self.view_options, self.budgets = view_options, budgets
        self.ack_window, self.settle, self.hooks = ack_window, settle, hooks
        max_ops, max_faces = budgets
        self.strict_bound = bool(strict_bound)
        self.cams = [served.mesh.new_camera(max_ops=max_ops, max_faces=max_faces, strict_bound=self.strict_bound)
                     for _ in range(cameras)]
        self.n_materials = self.cams[0].n_materials
        self.cache = cache
        self.cached, self.sums = [], []
        if cache is not None:
            from ..refine.cachedcamera import CachedCamera
            keys = served.vertex_keys if cache["strategy"] == "lru_pq" else None
            self.cached = [CachedCamera(cam, cache["vertices"], cache["strategy"], cache["pq_fraction"], keys)
                           for cam in self.cams]
            self.sums = [SlotChecksum(cache["vertices"]) for _ in self.cams]
        self.cond = threading.Condition()
        self.writer = threading.Lock()
        self.generation = 0          # bumped by every attach; a writer of an older one stops (ABORTED)
        self.attached = False
        self.detached_at = 0.0       # time.monotonic() when the stream broke
        self.end: End | None = None  # set: the attached stream ends so
        self.frame_seq = 0           # last frame made (and sent)
        self.acked = 0
        self.last_pose_seq = 0
        self.superseded = 0          # poses replaced since the last frame
        self.pending: list[_Pose | None] = [None] * cameras
        self.current: list[_Pose | None] = [None] * cameras     # the pose each camera is refined for
        self.due: list[float | None] = [None] * cameras         # when a convergence update may run
        self.keyframes: set[int] = set(range(cameras))          # frame 1 is a keyframe of every camera
        self.wakers: list = []       # callbacks that wake a waiting writer (any thread)
        self.frame_cpu = 1.0         # recent seconds to make a frame (an average); a first frame is not cheap
        self.held: list[HeldBuffers] | None = None     # OPS, OPS_LINKED: what each camera's client holds
        self.frame_encoding = pb.FRAME_ENCODING_RAW
        self._set_encoding(frame_encoding)

    def _set_encoding(self, encoding: int) -> None:
        """RAW, OPS or OPS_LINKED. Op streams from RAW start from a keyframe of every
        camera; between OPS and OPS_LINKED the held buffers stay (the client's are the same)."""
        if encoding == pb.FRAME_ENCODING_RAW:
            self.held = None
        else:
            links = self.served.op_links if encoding == pb.FRAME_ENCODING_OPS_LINKED else None
            if self.held is None:
                self.held = [HeldBuffers(self.n_materials) for _ in self.cams]
                self.keyframes.update(range(self.n_cameras))
            for held in self.held:
                held.links = links
        self.frame_encoding = encoding

    @property
    def cheap(self) -> bool:
        """Whether this session's frames have lately been quick to make."""
        return self.frame_cpu < CHEAP_SECONDS

    @property
    def n_cameras(self) -> int:
        return len(self.cams)

    @property
    def nbytes(self) -> int:
        """Bytes of the cameras' states (the static mesh is shared), with their caches' in cache mode."""
        return sum(c.nbytes for c in self.cams) + sum(c.nbytes + s.terms.nbytes for c, s in zip(self.cached, self.sums)) \
            + sum(h.nbytes for h in self.held or ())

    # -- streams --------------------------------------------------------------------
    def attach(self, last_frame_seq: int, view_options: dict | None = None, frame_encoding: int | None = None) -> int:
        """Start a stream on this session; returns its generation.

        A resumed client that missed frames gets a keyframe of every camera;
        the ack window restarts, since frames in flight on the old stream are
        gone. The previous stream, if any, ends with ABORTED.
        """
        with self.writer, self.cond:        # no frame is half made while we decide
            self.generation += 1
            if self.frame_seq and last_frame_seq != self.frame_seq:
                self.keyframes.update(range(self.n_cameras))
            self.acked = self.frame_seq
            if view_options is not None:
                self.view_options = view_options
            if frame_encoding is not None:
                self._set_encoding(frame_encoding)
            self.attached, self.end = True, None
            self._notify()
            return self.generation

    def detach(self, generation: int) -> tuple[bool, End | None]:
        """The stream of ``generation`` broke: (whether it was the attached one, now detached; the
        session's own end by then, if any: a Close or a refusal read just before the break)."""
        with self.cond:
            if generation != self.generation or not self.attached:
                return False, None
            self.attached = False
            self.detached_at = time.monotonic()
            return True, self.end

    def finish(self, end: End, generation: int | None = None) -> None:
        """End the attached stream with ``end`` (only if it is of ``generation``, when given)."""
        with self.cond:
            if generation is not None and generation != self.generation:
                return
            if self.end is None:
                self.end = end
            self._notify()

    # -- the reader's side ----------------------------------------------------------
    def accept(self, msg: pb.ClientMessage, generation: int, wake: bool = True) -> bool:
        """Take one client message after Open; raises Refused for a bad one.

        Returns False (and takes nothing) when the stream of ``generation``
        is no longer the session's: it was resumed elsewhere. ``wake=False``:
        do not call the wakers (the caller makes the frame that is due).
        """
        kind = msg.WhichOneof("kind")
        with self.cond:
            if generation != self.generation:
                return False
            if kind == "pose":
                self._accept_pose(msg.pose)
            elif kind == "ack":
                self._ack(msg.ack.frame_seq, "Ack")
            elif kind == "keyframe_request":
                req = msg.keyframe_request
                if req.HasField("camera"):
                    self._check_camera(req.camera, "KeyframeRequest")
                    self.keyframes.add(req.camera)
                else:
                    self.keyframes.update(range(self.n_cameras))
                self.hooks.keyframe_requested(req.reason)
            elif kind == "close":
                self.end = CLOSED
            elif kind == "open":
                raise Refused(grpc.StatusCode.INVALID_ARGUMENT, "Open sent twice on one stream; send it once, first")
            else:
                raise Refused(grpc.StatusCode.INVALID_ARGUMENT,
                              "a ClientMessage with no message set; set one of open, pose, ack, keyframe_request, close")
            if wake:
                self._notify()
            else:
                self.cond.notify_all()
            return True

    def _ack(self, frame_seq: int, what: str) -> None:
        if frame_seq > self.frame_seq:
            raise Refused(grpc.StatusCode.INVALID_ARGUMENT,
                          f"{what} of frame {frame_seq}, but the last frame sent is {self.frame_seq}; "
                          "ack only frames you applied")
        if frame_seq > self.acked:
            self.acked = frame_seq

    def _notify(self) -> None:
        """Wake whoever waits for this session's state to change (call under ``cond``)."""
        self.cond.notify_all()
        for wake in self.wakers:
            wake()

    def _check_camera(self, camera: int, what: str) -> None:
        if camera >= self.n_cameras:
            raise Refused(grpc.StatusCode.INVALID_ARGUMENT,
                          f"{what} for camera {camera}, but the session has cameras 0..{self.n_cameras - 1}")

    def _accept_pose(self, p: pb.CameraPose) -> None:
        from ..refine.view import check_pose
        self._check_camera(p.camera, "CameraPose")
        if p.pose_seq <= self.last_pose_seq:
            raise Refused(grpc.StatusCode.INVALID_ARGUMENT,
                          f"CameraPose.pose_seq {p.pose_seq} is not above the last one, {self.last_pose_seq}; "
                          "number poses 1, 2, 3, ... across the session's cameras")
        try:
            eye, target, up = check_pose(wire.from_vec3(p.eye), wire.from_vec3(p.target), wire.from_vec3(p.up))
        except InputError as exc:
            raise Refused(grpc.StatusCode.INVALID_ARGUMENT, f"CameraPose {p.pose_seq}: {exc}") from None
        if p.ack_frame_seq:
            self._ack(p.ack_frame_seq, "CameraPose.ack_frame_seq")
        if self.pending[p.camera] is not None:
            self.superseded += 1          # latest pose wins
        self.pending[p.camera] = _Pose(p.pose_seq, eye, target, up, time.monotonic())
        self.last_pose_seq = p.pose_seq

    # -- the writer's side ----------------------------------------------------------
    def poll(self, generation: int, stopped) -> End | float:
        """What the writer of the stream ``generation`` should do now: the
        End of the stream, 0.0 to make a frame (:meth:`make_frame`), or the
        seconds it may wait (a waker calls it sooner when anything changes).
        ``stopped()`` says the stream is gone."""
        with self.cond:
            if generation != self.generation:
                return End(grpc.StatusCode.ABORTED, "this session was resumed on another stream", False)
            if self.end is not None:
                return self.end
            if stopped():
                return End(grpc.StatusCode.CANCELLED, "the stream broke", False)
            return self._wait_seconds(time.monotonic())

    def _wait_seconds(self, now: float) -> float:
        """0 when a frame should be made now; else how long until one may be due."""
        if self.frame_seq >= self.acked + self.ack_window:
            return float("inf")                 # window full: an Ack wakes us
        if self.keyframes or any(p is not None for p in self.pending):
            return 0.0
        due = [d for d in self.due if d is not None]
        return max(min(due) - now, 0.0) if due else float("inf")

    def make_frame(self, generation: int) -> list | None:
        """Refine the cameras that have work and encode the frame: its
        serialized ServerMessage parts (bytes), or None when nothing is due after all (the
        window filled, or another stream took the session)."""
        with self.writer:
            started = time.thread_time()
            with self.cond:
                now = time.monotonic()
                if generation != self.generation or self._wait_seconds(now) > 0:
                    return None
                jobs = []
                for c in range(self.n_cameras):
                    pose, fresh = self.pending[c], True
                    if pose is None and self.due[c] is not None and self.due[c] <= now:
                        pose, fresh = self.current[c], False
                    if pose is not None or c in self.keyframes:
                        jobs.append((c, pose, fresh, c in self.keyframes))
                    self.pending[c] = None
                self.keyframes.clear()
                superseded, self.superseded = self.superseded, 0
                frame_seq, pose_high = self.frame_seq + 1, self.last_pose_seq
            cameras = [self._refine(c, pose, fresh, keyframe) for c, pose, fresh, keyframe in jobs]
            now = time.monotonic()
            for cam, (c, pose, fresh, _) in zip(cameras, jobs):
                if cam.stats is not None:
                    age = now - pose.received
                    cam.stats["pose_age_us"] = int(1e6 * age)
                    if fresh:
                        self.hooks.pose_answered(age)
            parts = wire.frame_parts(frame_seq, pose_high, superseded, cameras)
            with self.cond:
                self.frame_seq = frame_seq
            # CPU, not wall time: a frame that waited for the GIL is not an expensive one.
            self.frame_cpu = 0.8 * self.frame_cpu + 0.2 * (time.thread_time() - started)
            return parts

    def _refine(self, c: int, pose: _Pose | None, fresh: bool, keyframe: bool) -> wire.CameraFrameData:
        """One camera's update (when it has a pose to refine for) and its surfaces."""
        cam = self.cams[c]
        cached = self.cached[c] if self.cached else None
        out = wire.CameraFrameData(camera=c, pose_seq=0, keyframe=keyframe)
        touched = range(self.n_materials) if keyframe else ()
        if pose is not None:
            cpu = time.thread_time()
            if cached is None:
                # No View object: the pose was checked on arrival, the options at Open.
                delta = cam.update_params(view_params(pose.eye, pose.target, pose.up, **self.view_options))
            else:
                view = View(eye=pose.eye, target=pose.target, up=pose.up, **self.view_options)
                cd = cached.update(view, relax=fresh)     # a new pose may relax a raised tolerance
                delta = cd.delta
            cpu = time.thread_time() - cpu          # the CPU refinement really used, not wall time
            self.current[c] = pose
            converged = delta.operations == 0 and not delta.budget_exhausted
            self.due[c] = None if converged else time.monotonic() + (0.0 if delta.budget_exhausted else self.settle)
            out.stats = {"splits": delta.splits, "collapses": delta.collapses,
                         "update_us": int(1e6 * delta.seconds), "active_faces": cam.n_faces,
                         "budget_exhausted": delta.budget_exhausted, "updates": 1, "hidden_parts": cam.hidden_parts}
            self.hooks.refined(delta.seconds, delta.operations, cpu)
            if cached is not None:
                out.stats.update(cache_hits=cd.hits, cache_inserts=cd.inserted, cache_tolerance_px=cd.tolerance_px,
                                 updates=cd.updates)
                self.hooks.cached(cd.inserted, cd.hits)
            if keyframe:
                pass
            else:
                if cached is not None and cd.inserted:
                    out.vertices = self._slot_writes(c, cd.slots, cd.vertices)
                surfaces = delta.surfaces if cached is None else cd.surfaces
                held = self.held[c] if self.held is not None else None
                for m, d in sorted(surfaces.items()):
                    buf = cam.index_buffer(m) if cached is None else cached.slot_buffer(m)
                    s = wire.Surface(m, d.count, d.slots, d.tris, wire.buffer_crc32(buf))
                    if held is not None:
                        s.ops = _smaller_ops(held.encode(m, d.count, d.slots, d.tris), s)
                    out.surfaces.append(s)
        if keyframe and cached is not None:      # the client empties its slots: every active vertex again
            kd = cached.keyframe()
            self.sums[c].reset()
            out.vertices = self._slot_writes(c, kd.slots, kd.vertices)
        for m in touched:                        # a keyframe: every material's whole buffer
            (cam if cached is None else cached).reorder_for_vertex_cache(m)   # sent whole: in vertex-cache order
            buf = cam.index_buffer(m) if cached is None else cached.slot_buffer(m)
            out.surfaces.append(wire.Surface(m, len(buf), np.arange(len(buf), dtype=np.uint32), buf, wire.buffer_crc32(buf)))
            if self.held is not None:
                self.held[c].replace(m, buf)
        if touched and cached is None:
            cam.mark_sent()                      # the next delta's counts go on from the keyframe's
        if self.current[c] is not None:
            out.pose_seq = self.current[c].seq
        return out

    def _slot_writes(self, c: int, slots: np.ndarray, vertices: np.ndarray) -> wire.SlotWrites:
        """The attributes of ``vertices`` for ``slots`` of camera ``c``, and the slots checksum after them."""
        blocks = [np.asarray(b.data[vertices]) for b in self.served.blocks]
        self.sums[c].write(slots, blocks)
        return wire.SlotWrites(slots, blocks, self.sums[c].value)

    def held_buffer(self, camera: int, material: int) -> np.ndarray | None:
        """OPS: (count, 3) what the server takes camera's client to hold (None: RAW)."""
        return None if self.held is None else self.held[camera].buffer(material)

    def describe(self) -> dict:
        """Fields for the session's log lines."""
        out = {"session": self.token[:8], "mesh": self.served.name, "cameras": self.n_cameras,
               "client": self.client, "frame_seq": self.frame_seq, "pose_seq": self.last_pose_seq}
        if self.cache is not None:
            out["cache"] = f"{self.cache['vertices']} {self.cache['strategy']}"
        if self.strict_bound:
            out["strict_bound"] = True
        return out


def _smaller_ops(ops: bytes, s: wire.Surface) -> bytes | None:
    """``ops`` when it is smaller than the raw writes and fits a part whole; else None (send raw)."""
    return ops if len(ops) < s.wire_bytes and len(ops) <= wire.MAX_CHUNK_BYTES // 2 else None
