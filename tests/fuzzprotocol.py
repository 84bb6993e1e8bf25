"""Fuzz the caveclod.v1 protocol against a running server.

:func:`fuzz_protocol` drives a server on ``127.0.0.1:port`` with many
concurrent Session streams (one grpc.aio event loop, ``concurrency``
streams at a time over a few connections, requests serialized before they
are sent), each a *case* of several messages that :class:`CaseMaker` draws
from the seed and the case's number:

* ``valid``: a real session: an Open with random valid options (every
  field of the proto: cameras, budgets, ack window, vertex buffer hash,
  cache mode, strategy and fraction, frame encoding, client name, call
  metadata), then 8 to 48 poses, acks of the frames received so far, acks
  carried by poses and keyframe requests, sometimes a Close. ``resume``:
  the same, resuming a session an earlier case left (new options and
  encoding, last frame 0, 1, 3 or 2^64 - 1; two cases may resume one
  session at once: ABORTED), or with a token that names none. Both must end
  OK.
* ``wrong``: a valid session with one known mistake (pose before Open, Open
  twice, pose_seq not increasing, camera out of range, an ack of a frame
  never sent, a bad pose, option, camera count or cache mode, an unknown
  mesh, a resume with another camera count, an empty, garbage or oversized
  message). Must end with the status the proto documents for it; the
  client keeps its side open, so the server must end the stream by itself.
* ``field``: a valid session with fields anywhere in one message set to
  extreme values (NaN, +-inf, 1e308, 5e-324, subnormals, uint32/uint64
  max, long and odd strings, unknown enum values), or to another kind.
* ``raw``: fields appended at the wire level: negative and over-long
  varints for unsigned fields, NaN bit patterns, invalid UTF-8, wrong wire
  types, unknown field numbers, groups, lengths past the end.
* ``bytes``: one serialized message with bits flipped, cut short, bytes
  inserted, overwritten or doubled; ``random``: random bytes; ``list``: a
  ListMeshes request of odd bytes.

A stream ends as its case says: a half-close or Close (the server must end
it), the client cancelling (the session stays resumable until the resume
TTL), or, for ``wrong`` cases, nothing. The contract (:mod:`fuzzing`):
UNKNOWN or INTERNAL is a ``status`` finding; a status message with a
newline or over 1 KiB, a code the proto does not document, or another code
than a case's expected one is ``wrong``; a stream the server should have
ended but that reached its deadline is a ``hang``. A stream whose write
raced with the server's end of it loses its status (grpc.aio replaces it
with a local INTERNAL): it is counted as LOST_TO_A_WRITE, not judged.
Alongside, honest sessions (:func:`honest_session`: one resident with op
streams, one in cache mode with raw writes) fly over the mesh and must see
no checksum mismatch and no bad frame (else ``wrong``). At the end the
server must answer health (else ``hang``) and, given its metrics port, hold
no session once the resume TTL has passed (else ``leak``).

:func:`run_against_serve` starts ``caveclod serve`` for it (short resume
TTL, metrics on), and records a ``crash`` when the process died and a
``traceback`` when its log has one. From the command line::

    .venv/bin/python tests/fuzzprotocol.py --seconds 600 --seed 1 MESH.cvc

A finding names the seed and the case's number; :func:`replay` runs that
case again, alone (a resume then finds no earlier session).
"""

from __future__ import annotations

import asyncio
import collections
import math
import os
import random
import re
import struct
import sys
import threading
import time
import urllib.request
from dataclasses import dataclass, field

import grpc
import grpc.aio
from google.protobuf.descriptor import FieldDescriptor

from caveclod.v1 import caveclod_pb2 as pb

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))     # run as a script: fuzzing, service
from fuzzing import Budget, FuzzReport, finish, fuzzer_arguments, run_reported

Code = grpc.StatusCode
METHOD = "/caveclod.v1.Lod/Session"
STREAM_DEADLINE = 10.0      # seconds a stream may live; any case ends well within it on an idle server
END_SLACK = 10.0            # past its deadline, a stream that gRPC did not end is our own hang
CONCURRENCY = 24            # streams at once: enough to keep a 2-core server busy
CHANNELS = 4                # connections the streams are spread over
MAX_DETAILS = 1024          # a status message longer than this is a finding
MAX_MESSAGE = 64 * 1024     # the server's receive limit; bigger messages must get RESOURCE_EXHAUSTED
LEAK_SLACK = 5.0            # past the resume TTL, seconds for the reaper to free what is left
DEFAULT_TTL = 30            # seconds, when the server's resume TTL could not be learnt (caveclod serve's default)
POOL_SIZE = 8               # sessions remembered for resumes: the newest, most of them still resumable
EXAMPLE_BYTES = 160         # bytes of a mutated message shown in a finding
SETTLE_SECONDS = 0.01       # pause after a mutated message: a status that ends the stream arrives before
                            # the next write, which would otherwise race with it (see write_messages)

# A server's documented answers to a stream (the proto's "Errors"). UNAVAILABLE
# (draining) and UNAUTHENTICATED (no token) cannot happen against the servers
# fuzzed here, so they count as wrong.
DOCUMENTED = {Code.OK, Code.INVALID_ARGUMENT, Code.NOT_FOUND, Code.RESOURCE_EXHAUSTED, Code.ABORTED}
# Answers any case may get whatever it sent: the session limit, and a resume of its session elsewhere.
PREEMPTED = {Code.RESOURCE_EXHAUSTED, Code.ABORTED}
BUGS = {Code.UNKNOWN, Code.INTERNAL}

DOUBLES = (math.nan, -math.nan, math.inf, -math.inf, 1e308, -1e308, 1.7976931348623157e308, 5e-324, -5e-324,
           2.2250738585072014e-308, 1e-310, -0.0, 0.0, 1e154, -1e154, 1e-162, 3.4e38, 1e16, 180.0, 1e-300, 1.0,
           1e-290, 1e-100, 179.99999999999997)        # fields of view that pass, with errors multiplied enormously
UINT32S = (0, 1, 2, 3, 4, 5, 32, 33, 1 << 16, (1 << 31) - 1, 1 << 31, (1 << 32) - 2, (1 << 32) - 1)
UINT64S = UINT32S + (1 << 32, 1 << 53, (1 << 53) + 1, (1 << 63) - 1, 1 << 63, (1 << 64) - 1)
ENUMS = (-1, 0, 1, 2, 3, 4, 7, 1000, (1 << 31) - 1, -(1 << 31))
STRINGS = ("", "x", "x" * 200, "x" * 20_000, "x" * 70_000, "a\nb", "\r\n", "\x00", "caf\u00e9", "\U0001F986" * 500,
           "\u202e", "%s%n", "terrain\n", "../../etc/passwd", "'\"{}")
# Bit patterns of doubles, some of which Python cannot write as literals: signaling and negative NaNs.
DOUBLE_BITS = (0x7FF0000000000001, 0xFFF8000000000000, 0x7FF8000000000001, 0xFFFFFFFFFFFFFFFF,
               0x000FFFFFFFFFFFFF, 0x8000000000000001, 0x7FEFFFFFFFFFFFFF, 0x7FF0000000000000)
BAD_UTF8 = (b"\xff\xfe", b"\xc0\x80", b"\xed\xa0\x80", b"\x80", b"abc\xf4\x90\x80\x80")


# ------------------------------------------------------------------ the wire format, by hand


def varint(n: int) -> bytes:
    """Protobuf's unsigned LEB128 of ``n`` (negative: its 64-bit two's complement, 10 bytes)."""
    if n < 0:
        n += 1 << 64
    out = bytearray()
    while True:
        byte, n = n & 0x7F, n >> 7
        out.append(byte | (0x80 if n else 0))
        if not n:
            return bytes(out)


def tag(number: int, wire_type: int) -> bytes:
    return varint(number << 3 | wire_type)


def length_delimited(number: int, payload: bytes) -> bytes:
    return tag(number, 2) + varint(len(payload)) + payload


def nested(path: tuple, payload: bytes) -> bytes:
    """``payload`` (encoded fields) inside the sub-messages of field numbers ``path``.

    Appended to a serialized message, it is merged into that sub-message:
    protobuf merges a message field that occurs twice.
    """
    for number in reversed(path):
        payload = length_delimited(number, payload)
    return payload


# ------------------------------------------------------------------ the fields of a ClientMessage


def scalar_paths(descriptor, prefix: tuple = ()) -> list[tuple]:
    """Every scalar field under ``descriptor``, as the path of FieldDescriptors that reaches it."""
    out = []
    for f in descriptor.fields:
        if f.type == FieldDescriptor.TYPE_MESSAGE:
            out += scalar_paths(f.message_type, prefix + (f,))
        else:
            out.append(prefix + (f,))
    return out


PATHS = scalar_paths(pb.ClientMessage.DESCRIPTOR)
PATHS_BY_KIND = collections.defaultdict(list)
for _p in PATHS:
    PATHS_BY_KIND[_p[0].name].append(_p)
KINDS = tuple(PATHS_BY_KIND)


def extreme_value(rng: random.Random, f: FieldDescriptor):
    """A value of ``f``'s type at or past its limits."""
    t = f.type
    if t == FieldDescriptor.TYPE_DOUBLE:
        return rng.choice(DOUBLES)
    if t == FieldDescriptor.TYPE_UINT32:
        return rng.choice(UINT32S)
    if t == FieldDescriptor.TYPE_UINT64:
        return rng.choice(UINT64S)
    if t == FieldDescriptor.TYPE_BOOL:
        return rng.random() < 0.5
    if t == FieldDescriptor.TYPE_ENUM:
        return rng.choice(ENUMS)
    if t == FieldDescriptor.TYPE_STRING:
        return rng.choice(STRINGS)
    raise AssertionError(f"no extreme values for field {f.full_name} of type {t}")


def set_path(msg: pb.ClientMessage, path: tuple, value) -> None:
    """Set the field at ``path`` (creating the sub-messages on the way; another kind switches the oneof)."""
    target = msg
    for f in path[:-1]:
        target = getattr(target, f.name)
    setattr(target, path[-1].name, value)


def raw_field(rng: random.Random, f: FieldDescriptor) -> bytes:
    """One encoded occurrence of field ``f`` that a well-behaved client never sends."""
    n, t = f.number, f.type
    if t in (FieldDescriptor.TYPE_UINT32, FieldDescriptor.TYPE_UINT64, FieldDescriptor.TYPE_BOOL,
             FieldDescriptor.TYPE_ENUM):
        value = rng.choice((-1, -(1 << 31), (1 << 64) - 1, 1 << 32, 1 << 63, 2))
        return tag(n, 0) + varint(value)
    if t == FieldDescriptor.TYPE_DOUBLE:
        return tag(n, 1) + struct.pack("<Q", rng.choice(DOUBLE_BITS))
    if t == FieldDescriptor.TYPE_STRING:
        return length_delimited(n, rng.choice(BAD_UTF8))
    raise AssertionError(f"no raw values for field {f.full_name}")


def odd_field(rng: random.Random, number: int) -> bytes:
    """Field ``number`` with a wire type it does not have, an unknown field, or broken framing."""
    pick = rng.randrange(9)
    if pick == 0:
        return tag(number, 1) + rng.randbytes(8)                # fixed64 where a varint/LEN goes
    if pick == 1:
        return tag(number, 5) + rng.randbytes(4)                # fixed32
    if pick == 2:
        return length_delimited(number, rng.randbytes(rng.randrange(12)))
    if pick == 3:
        return tag(number, 0) + varint(rng.getrandbits(64))
    if pick == 4:
        unknown = rng.choice((15, 16, 99, 1000, (1 << 29) - 1))        # (1 << 29) - 1: the highest number
        return tag(unknown, 0) + varint(7) if rng.random() < 0.5 else length_delimited(unknown, b"ab")
    if pick == 5:
        return tag(number, 0) + b"\xff" * 10 + b"\x01"          # an over-long varint (11 bytes)
    if pick == 6:
        return tag(number, 2) + varint(1 << 20) + b"short"      # a length past the end
    if pick == 7:
        return tag(number, rng.choice((3, 4, 6, 7)))            # a group, or no wire type at all
    return b"\x00" + rng.randbytes(3)                          # field number 0


# ------------------------------------------------------------------ cases


@dataclass
class MeshTarget:
    """A served mesh, as ListMeshes describes it."""

    name: str
    vertex_buffer_hash: str
    vertices: int
    base_faces: int
    lo: tuple
    hi: tuple


@dataclass
class StreamState:
    """What one stream has received: its SessionInfo and the last frame that arrived in full."""

    info: pb.SessionInfo | None = None
    last_frame: int = 0
    frames: int = 0
    write_failed: bool = False    # a write failed as the server ended the stream: its status is lost
    resumed: bool = False         # SessionInfo.resumed
    got_info: asyncio.Event = field(default_factory=asyncio.Event)


@dataclass
class Case:
    """One stream: what to send, how to end it, and what the server must answer.

    ``messages`` are serialized ClientMessages, or functions of the
    StreamState that make one when it is sent (acks of the frames received,
    poses numbered after a resumed session's last one).
    """

    index: int
    kind: str                     # valid, resume, wrong, field, raw, bytes, random, list
    what: str                     # the mutation, enough to reproduce it with the seed
    messages: list
    ending: str = "half_close"    # half_close, cancel (after cancel_after messages), or hold (the server ends it)
    expect: tuple | None = None   # the codes the case may end with (None: any documented one)
    pause: float = 0.0            # seconds between messages
    cancel_after: int = 0
    wait_for_info: bool = False   # send the poses only once SessionInfo has arrived (a resume)
    record: dict | None = None    # the Open, to remember the session for a later resume
    example: bytes = b""          # the mutated message, for the report
    metadata: tuple = ()          # call metadata (the affinity key, a token the server does not ask for)
    mutated: int = -1             # the message mutated: after it, a pause for the server's answer
    method: str = "Session"       # or ListMeshes: one request, messages[0]


def _ack_of_last_frame(state: StreamState) -> bytes:
    return pb.ClientMessage(ack=pb.Ack(frame_seq=state.last_frame)).SerializeToString()


class _Pose:
    """A pose made when it is sent: numbered after the session's last pose (a resume), carrying an ack."""

    def __init__(self, pose: pb.CameraPose, carry_ack: bool):
        self.pose, self.carry_ack = pose, carry_ack

    def __call__(self, state: StreamState) -> bytes:
        pose = pb.CameraPose()
        pose.CopyFrom(self.pose)
        if state.info is not None and state.info.resumed:
            pose.pose_seq += state.info.last_pose_seq
        if self.carry_ack:
            pose.ack_frame_seq = state.last_frame
        return pb.ClientMessage(pose=pose).SerializeToString()


class CaseMaker:
    """Draws cases from ``rng`` for the meshes a server serves.

    ``pool`` holds sessions that earlier cases opened (token -> the Open
    they used), for resumes; the fuzzer adds to it as streams end.
    """

    def __init__(self, seed: int, meshes: list[MeshTarget], max_cameras: int = 4):
        self.seed, self.meshes, self.max_cameras = seed, meshes, max_cameras
        self.rng = random.Random(seed)
        # Which pooled session a resume takes depends on which streams happened to end first: a
        # random of its own, so that everything else about a case depends on the seed and its number.
        self.pool_rng = random.Random(seed + 1)
        self.pool: collections.OrderedDict[str, pb.Open] = collections.OrderedDict()
        self.made = 0

    def remember(self, token: str, opened: pb.Open) -> None:
        self.pool[token] = opened
        while len(self.pool) > POOL_SIZE:
            self.pool.popitem(last=False)

    def make(self, index: int | None = None) -> Case:
        """Case ``index`` (default: the next one), drawn from a random of its own: case N of a seed is
        the same whatever ran before it (but for the session a resume picks)."""
        if index is None:
            index, self.made = self.made, self.made + 1
        self.rng = rng = random.Random(self.seed * 1_000_003 + index)
        r = rng.random()
        if r < 0.18:
            return self.valid(index)
        if r < 0.26:
            return self.resume(index)
        if r < 0.46:
            return self.wrong(index)
        if r < 0.70:
            return self.field_mutation(index)
        if r < 0.82:
            return self.raw_mutation(index)
        if r < 0.96:
            return self.byte_mutation(index)
        if r < 0.98:
            return self.list_meshes(index)
        return self.random_bytes(index)

    # -- valid sessions ------------------------------------------------------------
    def mesh(self) -> MeshTarget:
        return self.rng.choice(self.meshes)

    def options(self) -> pb.RefineOptions:
        """RefineOptions a server must accept: every optional field set or not, at random."""
        rng = self.rng
        o = pb.RefineOptions(viewport_width=rng.choice((1, 64, 640, 1920, 8192)),
                             viewport_height=rng.choice((1, 48, 360, 1080, 8192)))
        if rng.random() < 0.5:
            o.fov_y_deg = rng.choice((0.01, 1.0, 45.0, 60.0, 90.0, 179.9))
        if rng.random() < 0.5:
            o.tolerance_px = rng.choice((0.0, 0.25, 1.0, 4.0, 100.0, 1e30))
        if rng.random() < 0.3:
            o.cull = rng.random() < 0.5
        if rng.random() < 0.3:
            o.backface = rng.random() < 0.5
        if rng.random() < 0.3:
            o.max_ops = rng.choice((1, 10, 1000, (1 << 64) - 1))
        if rng.random() < 0.3:
            o.max_faces = rng.choice((1, 100, 10_000, (1 << 64) - 1))
        if rng.random() < 0.2:
            o.strict_bound = rng.random() < 0.5
        return o

    def open(self, mesh: MeshTarget) -> pb.Open:
        """A valid Open of a new session of ``mesh``."""
        rng = self.rng
        msg = pb.Open(mesh=mesh.name, options=self.options(), cameras=rng.randint(1, self.max_cameras),
                      ack_window=rng.choice((0, 0, 1, 2, 4, 32, 33, (1 << 32) - 1)),
                      client=rng.choice(("", "fuzzprotocol/1", "x" * 300)),
                      frame_encoding=rng.choice((0, 1, 2, 2, 9)))          # 9: unknown, answered with RAW
        if rng.random() < 0.8:          # skip the vertex chunks most of the time: the server's work is elsewhere
            msg.vertex_buffer_hash = mesh.vertex_buffer_hash
        if rng.random() < 0.15:         # cache mode: at least the base mesh's vertices (<= 3 per base face)
            msg.cache_vertices = rng.choice((mesh.vertices, min(mesh.vertices, 3 * mesh.base_faces),
                                             (1 << 32) - 1))
            strategy = rng.choice((0, 1, 2, 3))
            msg.cache_strategy = strategy
            if strategy == pb.CACHE_STRATEGY_LRU_PQ and rng.random() < 0.5:
                msg.cache_pq_fraction = rng.choice((0.0, 0.1, 0.999))
        return msg

    def pose(self, mesh: MeshTarget, camera: int, seq: int) -> pb.CameraPose:
        """A valid pose of ``camera``: looking at a point of the mesh's box from above and aside."""
        rng = self.rng
        lo, hi = mesh.lo, mesh.hi
        extent = max(hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2], 1e-3)
        target = tuple(rng.uniform(lo[k], hi[k]) for k in range(3))
        reach = extent * rng.choice((0.01, 0.3, 1.0, 20.0))
        eye = (target[0] + reach * rng.uniform(0.1, 1.0) * rng.choice((-1, 1)),
               target[1] + reach * rng.uniform(-1.0, 1.0), hi[2] + reach * rng.uniform(0.0, 1.0))
        up = (0.0, 0.0, 1.0) if rng.random() < 0.9 else (rng.uniform(-1, 1), 1.0, rng.uniform(-1, 1))
        return pb.CameraPose(camera=camera, pose_seq=seq, eye=_vec3(eye), target=_vec3(target), up=_vec3(up))

    def body(self, mesh: MeshTarget, cameras: int, n: int) -> list:
        """``n`` valid messages after Open: poses (numbered 1, 2, ...), acks, keyframe requests."""
        rng, out, seq = self.rng, [], 0
        for _ in range(n):
            r = rng.random()
            if r < 0.65:
                seq += 1
                out.append(_Pose(self.pose(mesh, rng.randrange(cameras), seq), carry_ack=rng.random() < 0.3))
            elif r < 0.85:
                out.append(_ack_of_last_frame)
            elif r < 0.95:
                req = pb.KeyframeRequest(reason=rng.choice((0, 1, 2, 3)), frame_seq=rng.choice((0, 1, 7)),
                                         detail=rng.choice(("", "material 0: crc 0x1a2b3c4d")))
                if rng.random() < 0.6:
                    req.camera = rng.randrange(cameras)
                out.append(pb.ClientMessage(keyframe_request=req).SerializeToString())
            else:
                out.append(pb.ClientMessage(ack=pb.Ack(frame_seq=0)).SerializeToString())   # an ack of nothing
        return out

    def session(self, index: int, kind: str, opened: pb.Open | None = None) -> Case:
        """A valid session (of ``opened``, or a new Open) with a random end: Close, half-close or a cancel."""
        rng = self.rng
        if opened is None:
            opened = self.open(self.mesh())
        mesh = next((m for m in self.meshes if m.name == opened.mesh), self.meshes[0])
        messages = [pb.ClientMessage(open=opened).SerializeToString()]
        messages += self.body(mesh, opened.cameras, rng.randint(8, 48))
        case = Case(index, kind, f"{mesh.name} cameras {opened.cameras}", messages, record={"open": opened},
                    pause=rng.choice((0.0, 0.0, 0.0, 0.002, 0.01)))
        if rng.random() < 0.1:           # metadata a server without tokens and balancers ignores
            case.metadata = (("x-caveclod-session", rng.choice(("0" * 32, "", "k" * 2000))),
                             ("authorization", rng.choice(("Bearer nothing", "Basic x", ""))))
        ending = rng.random()
        if ending < 0.3:
            case.messages.append(pb.ClientMessage(close=pb.Close(reason=rng.choice(("", "done")))).SerializeToString())
            case.ending = "hold"               # the Close must end it
        elif ending < 0.75:
            case.ending = "half_close"         # a Close too (the proto)
        else:
            case.ending, case.cancel_after = "cancel", rng.randint(1, len(case.messages))
        return case

    def valid(self, index: int) -> Case:
        case = self.session(index, "valid")
        case.expect = (Code.OK,) if case.ending != "cancel" else None
        return case

    def resume(self, index: int) -> Case:
        """A resume of an earlier session (new options and encoding allowed; the session may have
        expired meanwhile, which starts a fresh one), or of a token that is not one."""
        rng = self.rng
        fresh = self.open(self.mesh())
        pooled, no_token = rng.random() < 0.8, rng.choice(("no-such-session", "", "\x00" * 40, "A" * 10_000))
        if self.pool and pooled:
            token = self.pool_rng.choice(list(self.pool))
            opened = pb.Open()
            opened.CopyFrom(self.pool[token])
            opened.options.CopyFrom(fresh.options)
            opened.options.ClearField("max_ops")       # budgets stay as opened: leave them unset
            opened.options.ClearField("max_faces")
            opened.options.ClearField("strict_bound")  # as does the strict bound
            opened.frame_encoding = fresh.frame_encoding
            what = "resume of an earlier session"
        else:
            token, what = no_token, "resume of no session"
            opened = fresh
        opened.resume_token = token
        opened.last_frame_seq = rng.choice((0, 1, 3, (1 << 64) - 1))
        case = self.session(index, "resume", opened)
        case.what = f"{what} {token[:12]!r}"
        case.wait_for_info = True          # poses are numbered after SessionInfo.last_pose_seq
        case.expect = (Code.OK,) if case.ending != "cancel" else None
        return case

    # -- valid sessions with one known mistake ----------------------------------------
    def wrong(self, index: int) -> Case:
        """A session with one mistake the proto names, and the status it must end with.

        The client keeps its side open: the server must end the stream by itself.
        """
        rng = self.rng
        mesh = self.mesh()
        opened = self.open(mesh)
        opened.ClearField("cache_vertices")       # cache fields only where a mistake puts them
        opened.cache_strategy = 0
        opened.ClearField("cache_pq_fraction")
        body = self.body(mesh, opened.cameras, rng.randint(0, 20))
        poses = sum(isinstance(m, _Pose) for m in body)
        mistakes = (self._wrong_sequence, self._wrong_pose, self._wrong_open, self._wrong_bytes)
        what, bad, where, expect = rng.choice(mistakes)(mesh, opened, poses)
        data = bad if isinstance(bad, bytes) else bad.SerializeToString()
        # where: "first" (the mistake is the first message), or "after" an Open and a valid body.
        before = [] if where == "first" else [pb.ClientMessage(open=opened).SerializeToString(), *body]
        ending = "hold"
        if Code.OK in expect:                     # it may be served: then our half-close ends it
            ending = "half_close"
        return Case(index, "wrong", what, before + [data], ending=ending, expect=expect,
                    example=data[:EXAMPLE_BYTES])

    def _wrong_sequence(self, mesh: MeshTarget, opened: pb.Open, poses: int) -> tuple:
        """Messages out of order: before Open, Open twice, pose_seq not increasing, acks of unsent frames."""
        rng = self.rng
        invalid = (Code.INVALID_ARGUMENT,)
        pick = rng.randrange(7)
        if pick == 0:
            return "a pose before Open", pb.ClientMessage(pose=self.pose(mesh, 0, 1)), "first", invalid
        if pick == 1:
            kind = rng.choice(("ack", "keyframe_request", "close"))
            return f"{kind} before Open", pb.ClientMessage(**{kind: getattr(pb, _TYPE[kind])()}), "first", invalid
        if pick == 2:
            again = opened if rng.random() < 0.5 else self.open(mesh)
            return "Open twice", pb.ClientMessage(open=again), "after", invalid
        if pick == 3:
            seq = rng.randint(0, poses)
            return f"pose_seq {seq} after {poses}", pb.ClientMessage(pose=self.pose(mesh, 0, seq)), "after", invalid
        if pick == 4:
            seq = rng.choice((1000, 1 << 40, (1 << 64) - 1))
            if rng.random() < 0.5:
                ack = pb.ClientMessage(ack=pb.Ack(frame_seq=seq))
                return f"an ack of frame {seq}, never sent", ack, "after", invalid
            pose = self.pose(mesh, 0, poses + 1)
            pose.ack_frame_seq = seq
            return f"a pose acking frame {seq}, never sent", pb.ClientMessage(pose=pose), "after", invalid
        if pick == 5 and self.pool:
            token = self.pool_rng.choice(list(self.pool))
            resumed = pb.Open()
            resumed.CopyFrom(self.pool.pop(token))            # refused: the session is discarded
            resumed.resume_token = token
            if self.pool_rng.random() < 0.5:
                resumed.mesh = "nowhere"
                return "a resume naming a mesh not served", pb.ClientMessage(open=resumed), "first", (Code.NOT_FOUND,)
            resumed.cameras = resumed.cameras % self.max_cameras + 1
            # Refused, unless the session expired meanwhile: then it is a new session, served.
            return "a resume with another camera count", pb.ClientMessage(open=resumed), "first", \
                (Code.INVALID_ARGUMENT, Code.OK)
        return "a message with no kind after Open", pb.ClientMessage(), "after", invalid

    def _wrong_pose(self, mesh: MeshTarget, opened: pb.Open, poses: int) -> tuple:
        """A pose or keyframe request the session cannot take: camera out of range, coordinates check_pose refuses."""
        rng = self.rng
        invalid = (Code.INVALID_ARGUMENT,)
        pick = rng.randrange(3)
        if pick == 0:
            camera = rng.choice((opened.cameras, opened.cameras + 1, (1 << 32) - 1))
            return f"a pose of camera {camera} of {opened.cameras}", \
                pb.ClientMessage(pose=self.pose(mesh, camera, poses + 1)), "after", invalid
        if pick == 1:
            camera = rng.choice((opened.cameras, (1 << 32) - 1))
            return f"a keyframe request of camera {camera} of {opened.cameras}", \
                pb.ClientMessage(keyframe_request=pb.KeyframeRequest(camera=camera)), "after", invalid
        pose, what = self.bad_pose(mesh, poses + 1)
        return what, pb.ClientMessage(pose=pose), "after", invalid

    def _wrong_open(self, mesh: MeshTarget, opened: pb.Open, poses: int) -> tuple:
        """An Open the server must refuse: options, cameras, cache mode, mesh."""
        rng = self.rng
        invalid = (Code.INVALID_ARGUMENT,)
        pick = rng.randrange(4)
        if pick == 0:
            what = self.bad_options(opened)
        elif pick == 1:
            opened.cameras = rng.choice((0, self.max_cameras + 1, (1 << 32) - 1))
            what = f"Open of {opened.cameras} cameras"
        elif pick == 2:
            what = self.bad_cache(opened, mesh)
        else:
            opened.mesh = rng.choice(("nowhere", "", mesh.name + "\n", "x" * 30_000, mesh.name.upper() + "."))
            return f"unknown mesh {opened.mesh[:20]!r}", pb.ClientMessage(open=opened), "first", (Code.NOT_FOUND,)
        return what, pb.ClientMessage(open=opened), "first", invalid

    def _wrong_bytes(self, mesh: MeshTarget, opened: pb.Open, poses: int) -> tuple:
        """Messages that are not ClientMessages, or too big for the server."""
        rng = self.rng
        where = rng.choice(("first", "after"))
        pick = rng.randrange(3)
        if pick == 0:
            return "an empty ClientMessage", b"", where, (Code.INVALID_ARGUMENT,)
        if pick == 1:
            return "garbage", b"\xff\xff\xff\xff\x0f garbage \x00\x01", where, (Code.INVALID_ARGUMENT,)
        big = pb.ClientMessage(keyframe_request=pb.KeyframeRequest(detail="x" * (MAX_MESSAGE + 100)))
        return "an oversized message", big, where, (Code.RESOURCE_EXHAUSTED,)

    def bad_pose(self, mesh: MeshTarget, seq: int) -> tuple[pb.CameraPose, str]:
        """A pose check_pose must refuse (not finite, eye == target, up zero or along the view,
        overflowing), and what is wrong with it."""
        rng = self.rng
        pose = self.pose(mesh, 0, seq)
        pick = rng.randrange(5)
        if pick == 0:
            vec, axis, value = rng.choice(("eye", "target", "up")), rng.choice("xyz"), rng.choice((math.inf, -math.inf,
                                                                                                  math.nan))
            setattr(getattr(pose, vec), axis, value)
            return pose, f"pose {vec}.{axis} {value}"
        if pick == 1:
            pose.eye.CopyFrom(pose.target)
            return pose, "pose eye == target"
        if pick == 2:
            pose.up.CopyFrom(pb.Vec3(x=rng.choice((0.0, -0.0))))       # (a tiny up is a direction like any other)
            return pose, f"pose up ({pose.up.x}, 0, 0)"
        if pick == 3:
            pose.up.CopyFrom(pb.Vec3(x=pose.target.x - pose.eye.x, y=pose.target.y - pose.eye.y,
                                     z=pose.target.z - pose.eye.z))
            return pose, "pose up along the view"
        pose.eye.CopyFrom(pb.Vec3(x=1e308, y=0.0, z=1.0))
        pose.target.CopyFrom(pb.Vec3(x=-1e308, y=0.0, z=0.0))
        return pose, "pose eye and target overflowing apart"

    def bad_options(self, opened: pb.Open) -> str:
        """Set one RefineOptions field of ``opened`` out of its documented range; says which."""
        rng = self.rng
        o = opened.options
        pick = rng.randrange(7)
        if pick == 0:
            setattr(o, rng.choice(("viewport_width", "viewport_height")), 0)
        elif pick == 1:
            o.fov_y_deg = rng.choice((0.0, -1.0, 180.0, 1e308, math.nan, math.inf, 5e-324, -5e-324, 1e-310))
        elif pick == 2:
            o.tolerance_px = rng.choice((-1.0, -5e-324, math.inf, -math.inf, math.nan))
        elif pick == 3:
            o.max_ops = 0
        elif pick == 4:
            o.max_faces = 0
        elif pick == 5:
            o.fov_y_deg = 1e-300          # so narrow that pixels per unit overflow
            o.viewport_height = (1 << 32) - 1
        else:
            o.viewport_width = o.viewport_height = 0
        return f"Open.options {_one_line(o)}"

    def bad_cache(self, opened: pb.Open, mesh: MeshTarget) -> str:
        """Set cache fields of ``opened`` that the proto refuses; says which."""
        rng = self.rng
        pick = rng.randrange(5)
        if pick == 0:
            opened.cache_vertices = 0
        elif pick == 1:
            opened.cache_strategy = rng.choice((1, 2, 3))            # a strategy without cache_vertices
        elif pick == 2:
            opened.cache_pq_fraction = 0.1                           # a fraction without cache_vertices
        elif pick == 3:
            opened.cache_vertices = mesh.vertices
            opened.cache_strategy = rng.choice((0, 1, 2, 3))
            if opened.cache_strategy == pb.CACHE_STRATEGY_LRU_PQ:
                opened.cache_pq_fraction = rng.choice((1.0, -0.1, math.nan, math.inf, 1e308))
            else:
                opened.cache_pq_fraction = 0.1                       # with a strategy that has no queue
        else:
            opened.cache_vertices = rng.choice((1, 2))               # fewer than the base mesh's
        return (f"Open cache_vertices {opened.cache_vertices if opened.HasField('cache_vertices') else 'unset'} "
                f"strategy {opened.cache_strategy} pq_fraction "
                f"{opened.cache_pq_fraction if opened.HasField('cache_pq_fraction') else 'unset'}")

    # -- mutations ----------------------------------------------------------------------
    def mutated_session(self, index: int, kind: str) -> tuple[Case, int, pb.ClientMessage]:
        """A valid session, a message of it picked for mutation (index, parsed); the session ends by a half-close."""
        rng = self.rng
        case = self.session(index, kind)
        case.ending = "half_close"        # (a Close the mutation hits may be a Close no more)
        case.pause = 0.0
        at = rng.randrange(len(case.messages)) if rng.random() < 0.7 else 0
        item = case.messages[at]
        data = item(StreamState()) if callable(item) else item
        return case, at, pb.ClientMessage.FromString(data)

    def field_mutation(self, index: int) -> Case:
        """Fields of one message set to extreme values (sometimes of another kind of message)."""
        rng = self.rng
        case, at, msg = self.mutated_session(index, "field")
        kind = msg.WhichOneof("kind")
        changes = []
        for _ in range(rng.choice((1, 1, 2, 3))):
            path = rng.choice(PATHS_BY_KIND[kind] if rng.random() < 0.9 else PATHS)
            value = extreme_value(rng, path[-1])
            set_path(msg, path, value)
            changes.append(f"{'.'.join(f.name for f in path)}={_short(value)}")
        if rng.random() < 0.05:
            msg.Clear()                   # an empty ClientMessage
            changes.append("cleared")
        data = msg.SerializeToString()
        case.messages[at], case.mutated = data, at
        case.what = f"message {at}: {', '.join(changes)}"
        case.example = data[:EXAMPLE_BYTES]
        return case

    def raw_mutation(self, index: int) -> Case:
        """Encoded fields appended to one message: values and framing its fields never have."""
        rng = self.rng
        case, at, msg = self.mutated_session(index, "raw")
        kind = msg.WhichOneof("kind") or rng.choice(KINDS)
        data = msg.SerializeToString()
        changes = []
        for _ in range(rng.choice((1, 1, 2))):
            path = rng.choice(PATHS_BY_KIND[kind])
            numbers = tuple(f.number for f in path[:-1])
            if rng.random() < 0.6:
                extra, how = raw_field(rng, path[-1]), "bad value"
            else:
                extra, how = odd_field(rng, path[-1].number), "odd framing"
            data += nested(numbers, extra)
            changes.append(f"{'.'.join(f.name for f in path)}: {how}")
        case.messages[at], case.mutated = data, at
        case.what = f"message {at}: {', '.join(changes)}"
        case.example = data[:EXAMPLE_BYTES]
        return case

    def byte_mutation(self, index: int) -> Case:
        """One serialized message with bits flipped, cut short, or bytes inserted or overwritten."""
        rng = self.rng
        case, at, msg = self.mutated_session(index, "bytes")
        data = bytearray(msg.SerializeToString())
        how = rng.randrange(5)
        if how == 0 and data:
            for _ in range(rng.randint(1, 4)):
                bit = rng.randrange(8 * len(data))
                data[bit // 8] ^= 1 << (bit % 8)
            what = "bits flipped"
        elif how == 1 and data:
            del data[rng.randrange(len(data)):]
            what = "cut short"
        elif how == 2:
            at_byte = rng.randrange(len(data) + 1)
            data[at_byte:at_byte] = rng.randbytes(rng.randint(1, 8))
            what = "bytes inserted"
        elif how == 3 and data:
            data[rng.randrange(len(data))] = rng.choice((0x00, 0x7F, 0x80, 0xFF))
            what = "a byte overwritten"
        else:
            data = data + data
            what = "doubled"
        case.messages[at], case.mutated = bytes(data), at
        case.what = f"message {at}: {what}"
        case.example = bytes(data[:EXAMPLE_BYTES])
        return case

    def list_meshes(self, index: int) -> Case:
        """A ListMeshes request: empty, with unknown fields, or random bytes (OK or INVALID_ARGUMENT)."""
        rng = self.rng
        data = rng.choice((b"", tag(1, 0) + varint(rng.getrandbits(64)), length_delimited(7, b"x" * 100),
                           rng.randbytes(rng.choice((1, 3, 30)))))
        return Case(index, "list", "ListMeshes", [data], expect=(Code.OK, Code.INVALID_ARGUMENT),
                    method="ListMeshes", example=data[:EXAMPLE_BYTES])

    def random_bytes(self, index: int) -> Case:
        """Random bytes, after an Open or instead of one."""
        rng = self.rng
        mesh = self.mesh()
        messages = [pb.ClientMessage(open=self.open(mesh)).SerializeToString()] if rng.random() < 0.7 else []
        junk = [rng.randbytes(rng.choice((1, 2, 5, 20, 200, 2000))) for _ in range(rng.randint(1, 5))]
        return Case(index, "random", f"{len(junk)} random messages{' after Open' if messages else ''}",
                    messages + junk, example=junk[0][:EXAMPLE_BYTES], mutated=len(messages))


_TYPE = {"ack": "Ack", "keyframe_request": "KeyframeRequest", "close": "Close"}


def _vec3(p) -> pb.Vec3:
    return pb.Vec3(x=p[0], y=p[1], z=p[2])


def _one_line(msg) -> str:
    from google.protobuf import text_format
    return text_format.MessageToString(msg, as_one_line=True)[:200]


def _short(value) -> str:
    text = repr(value)
    return text if len(text) <= 24 else f"{text[:12]}...({len(value)} chars)"


# ------------------------------------------------------------------ running cases


def _identity(b: bytes) -> bytes:
    return b


async def read_responses(call, state: StreamState) -> None:
    """Read the stream to its end, noting SessionInfo and each frame's number (the last part of a frame)."""
    try:
        while True:
            data = await call.read()
            if data is grpc.aio.EOF:
                return
            msg = pb.ServerMessage.FromString(data)
            kind = msg.WhichOneof("kind")
            if kind == "session_info":
                state.info = msg.session_info
                state.got_info.set()
                state.resumed = msg.session_info.resumed
            elif kind == "frame" and not msg.frame.continued:
                state.last_frame = msg.frame.frame_seq
                state.frames += 1
    except grpc.RpcError:
        return
    except asyncio.CancelledError:
        if not call.cancelled():        # our task was cancelled, not the call (grpc.aio raises this for both)
            raise
    finally:
        state.got_info.set()               # a writer waiting for SessionInfo stops waiting


async def info_before_second(case: Case, state: StreamState, i: int) -> bool:
    """Before message ``i == 1`` of a case that waits for it, wait for SessionInfo; False when none came."""
    if i == 1 and case.wait_for_info and state.info is None:
        try:
            await asyncio.wait_for(state.got_info.wait(), STREAM_DEADLINE)
        except asyncio.TimeoutError:
            return False
    return True


async def write_messages(call, case: Case, state: StreamState) -> int:
    """Send the case's messages as far as the stream takes them; end our side as the case says.

    Returns how many messages were written.
    """
    sent = 0
    for i, item in enumerate(case.messages):
        if case.ending == "cancel" and i >= case.cancel_after:
            break
        if call.done() or not await info_before_second(case, state, i):
            break
        data = item(state) if callable(item) else item
        try:
            await call.write(data)
        except grpc.aio.AioRpcError as exc:
            # A write that raced with the server's end of the stream: grpc.aio then replaces the
            # server's status with a local INTERNAL "Internal error from Core", and the status the
            # server sent is lost (so is this case's verdict).
            state.write_failed = exc.code() == Code.INTERNAL and "execute_batch" in (exc.debug_error_string() or "")
            break
        except (grpc.RpcError, asyncio.InvalidStateError):
            break
        sent += 1
        if case.pause or i == case.mutated:
            await asyncio.sleep(max(case.pause, SETTLE_SECONDS if i == case.mutated else 0.0))
    try:
        if case.ending == "cancel":
            call.cancel()
        elif case.ending == "half_close":
            await call.done_writing()
    except (grpc.RpcError, asyncio.InvalidStateError):
        pass
    return sent


async def run_case(channel, case: Case, maker: CaseMaker, report: FuzzReport, seed: int) -> None:
    """One stream: send the case, wait for its end (bounded), judge it, remember its session for resumes."""
    if case.method == "ListMeshes":
        return await run_list_case(channel, case, report, seed)
    call = channel.stream_stream(METHOD, request_serializer=_identity, response_deserializer=_identity)(
        timeout=STREAM_DEADLINE, metadata=case.metadata)
    state = StreamState()
    debug = ""
    reader = asyncio.ensure_future(read_responses(call, state))
    try:
        sent = await write_messages(call, case, state)
        try:
            code = await asyncio.wait_for(call.code(), STREAM_DEADLINE + END_SLACK)
            details = await call.details() or ""
            if code in BUGS:            # where it came from: the server ("received from peer") or our own gRPC
                debug = await call.debug_error_string() or ""
        except asyncio.TimeoutError:
            code, details = None, "the client's own stream did not end (gRPC missed its deadline)"
        await asyncio.wait({reader}, timeout=END_SLACK)     # the responses after the status (no raise)
    finally:
        if not call.done():
            call.cancel()
        if not reader.done():
            reader.cancel()
    if state.write_failed and code == Code.INTERNAL:
        _count(report, sent, state)
        report.outcome("LOST_TO_A_WRITE")
        return
    settle(case, state, sent, code, details, maker, report, seed, debug)


def _count(report: FuzzReport, sent: int, state: StreamState) -> None:
    report.count("messages", sent)
    report.count("streams")
    report.count("frames", state.frames)
    report.count("resumed", state.resumed)


def settle(case: Case, state: StreamState, sent: int, code: Code | None, details: str, maker: CaseMaker,
           report: FuzzReport, seed: int, debug: str = "") -> None:
    """Count a finished stream, judge its end, and remember a cancelled session for resumes."""
    _count(report, sent, state)
    report.outcome(code.name if code is not None else "NO_END")
    verdict = judge(case, code, details)
    if verdict is not None:
        kind, detail = verdict
        report.add(kind, describe(case, seed), detail + (f" ({debug[:300]})" if debug else ""))
    if state.info is not None and case.record is not None and code == Code.CANCELLED:
        # A cancelled session waits for a resume (until the resume TTL: the pool keeps the newest few).
        opened = pb.Open()
        opened.CopyFrom(case.record["open"])
        opened.ClearField("resume_token")
        opened.last_frame_seq = 0
        maker.remember(state.info.session_token, opened)


CODES = {c.value[0]: c for c in Code}


async def run_case_ws(http, url: str, case: Case, maker: CaseMaker, report: FuzzReport, seed: int) -> None:
    """One case as a WebSocket session (``caveclod serve --web-port``; the proto's "WebSocket"):
    the same messages, one per binary message, judged by the session's final ServerMessage.status
    as a gRPC stream is by its status; the close code must be the status's (1000 or 4000 + code).

    A WebSocket has no half-close: a case that half-closes sends Close instead (the proto treats
    both alike); a case that cancels closes the connection (the session stays resumable).
    """
    import aiohttp
    state = StreamState()
    status: list = []
    try:
        ws = await asyncio.wait_for(http.ws_connect(url, protocols=["caveclod.v1"], max_msg_size=0,
                                                    timeout=aiohttp.ClientWSTimeout(ws_close=STREAM_DEADLINE)),
                                    STREAM_DEADLINE)
    except (aiohttp.ClientError, asyncio.TimeoutError) as exc:
        report.add("wrong", describe(case, seed), f"the WebSocket did not open: {exc!r}")
        return

    async def read() -> None:
        try:
            async for msg in ws:
                if msg.type != aiohttp.WSMsgType.BINARY:
                    break
                reply = pb.ServerMessage.FromString(msg.data)
                kind = reply.WhichOneof("kind")
                if kind == "session_info":
                    state.info, state.resumed = reply.session_info, reply.session_info.resumed
                    state.got_info.set()
                elif kind == "frame" and not reply.frame.continued:
                    state.last_frame = reply.frame.frame_seq
                    state.frames += 1
                elif kind == "status":
                    status.append(reply.status)
        finally:
            state.got_info.set()

    reader = asyncio.ensure_future(read())
    sent, hung = 0, False
    try:
        for i, item in enumerate(case.messages):
            if (case.ending == "cancel" and i >= case.cancel_after) or ws.closed or reader.done() \
                    or not await info_before_second(case, state, i):
                break
            try:
                await ws.send_bytes(item(state) if callable(item) else item)
            except (ConnectionError, RuntimeError):
                break
            sent += 1
            if case.pause or i == case.mutated:
                await asyncio.sleep(max(case.pause, SETTLE_SECONDS if i == case.mutated else 0.0))
        try:
            if case.ending == "cancel":
                await ws.close()
            elif case.ending == "half_close" and not ws.closed:
                await ws.send_bytes(pb.ClientMessage(close=pb.Close(reason="half-close")).SerializeToString())
        except (ConnectionError, RuntimeError):
            pass
        try:
            await asyncio.wait_for(asyncio.shield(reader), STREAM_DEADLINE + END_SLACK)
        except asyncio.TimeoutError:
            hung = True
    finally:
        reader.cancel()
        await ws.close()
    if status:
        code, details = CODES.get(status[-1].code, Code.UNKNOWN), status[-1].message
        want = 1000 if code == Code.OK else 4000 + code.value[0]
        if ws.close_code != want:
            report.add("wrong", describe(case, seed), f"status {code.name} closed with {ws.close_code}, not {want}")
    elif case.ending == "cancel":
        code, details = Code.CANCELLED, "the client closed the WebSocket"
    else:
        code, details = None, ("the session did not end within the deadline" if hung else
                               f"the WebSocket closed ({ws.close_code}) without a status")
    settle(case, state, sent, code, details, maker, report, seed)


async def run_list_case(channel, case: Case, report: FuzzReport, seed: int) -> None:
    """One ListMeshes call with the case's request bytes, judged like a stream."""
    call = channel.unary_unary("/caveclod.v1.Lod/ListMeshes", request_serializer=_identity,
                               response_deserializer=_identity)
    try:
        await call(case.messages[0], timeout=STREAM_DEADLINE)
        code, details = Code.OK, ""
    except grpc.aio.AioRpcError as exc:
        code, details = exc.code(), exc.details() or ""
    report.count("messages")
    report.count("list_calls")
    report.outcome(code.name)
    verdict = judge(case, code, details)
    if verdict is not None:
        report.add(verdict[0], describe(case, seed), verdict[1])


def replay(port: int, seed: int, index: int) -> tuple[str, list]:
    """Run case ``index`` of ``seed`` alone against the server on ``port``; returns (what the case
    is, the findings). Resumes find no earlier session: they start fresh ones."""
    report = FuzzReport("replay")

    async def one() -> Case:
        channel = grpc.aio.insecure_channel(f"127.0.0.1:{port}")
        try:
            maker = CaseMaker(seed, await list_meshes(channel))
            case = maker.make(index)
            await run_case(channel, case, maker, report, seed)
            return case
        finally:
            await channel.close()

    case = asyncio.run(one())
    return describe(case, seed) + f" -> {report.outcomes}", report.findings


def judge(case: Case, code: Code | None, details: str) -> tuple[str, str] | None:
    """(finding kind, detail) when the stream's end breaks the contract; None when it keeps it."""
    said = f"{code.name if code else 'no end'}: {details!r}"
    if code in BUGS:
        return "status", said
    if "\n" in details or "\r" in details or len(details) > MAX_DETAILS:
        return "wrong", f"a status message of {len(details)} characters, or not one line: {said}"
    if code is None or code == Code.DEADLINE_EXCEEDED:
        # Every case ends its stream, or has the server end it, well within the deadline (a
        # case that cancels does so unless it waited that long for a SessionInfo).
        return "hang", f"the stream was not over within {STREAM_DEADLINE} s: {said}"
    if code == Code.CANCELLED:
        return None if case.ending == "cancel" else ("wrong", f"cancelled, but not by us: {said}")
    if code not in DOCUMENTED:
        return "wrong", f"a status the proto does not document here: {said}"
    if case.expect is not None and code not in case.expect and code not in PREEMPTED:
        return "wrong", f"expected {' or '.join(c.name for c in case.expect)}, got {said}"
    return None


def describe(case: Case, seed: int) -> str:
    """How to find the case again: seed, number, kind, what was done (and the mutated message's bytes)."""
    text = f"seed {seed} case {case.index} [{case.kind}] {case.what} ({len(case.messages)} messages, {case.ending})"
    if case.example:
        text += f" bytes {case.example.hex()}"
    return text


# ------------------------------------------------------------------ honest sessions


async def honest_session(target: str, mesh: MeshTarget, stop: asyncio.Event, report: FuzzReport,
                         cache: bool) -> None:
    """Fly over ``mesh`` until ``stop``, checking every frame's checksums (the client does);
    any divergence, bad frame or end of the session is a ``wrong`` finding."""
    from caveclod.client.aio import AsyncClient
    from caveclod.client.session import SessionEnded
    from caveclod.paths import flyover
    name = f"honest session ({'cache mode, raw writes' if cache else 'resident, op streams'})"
    # Both encodings: op streams for the resident session, raw writes in cache mode.
    options = {"cache_vertices": min(mesh.vertices, max(mesh.vertices // 2, 3 * mesh.base_faces)),
               "frame_encoding": "raw"} if cache else {}
    frames = 0
    try:
        async with AsyncClient(target, cache_dir=False) as client:
            session = await client.session(mesh.name, width=640, height=360, timeout=60.0, **options)
            t, deadline = 0.0, time.monotonic() + 3600.0
            while not stop.is_set() and time.monotonic() < deadline:
                session.send_pose(0, *flyover(mesh.lo, mesh.hi, 0, t, seconds_per_lap=20.0))
                t += 1 / 30
                if await session.next_frame(timeout=1.0) is not None:
                    frames += 1
            protocol = session.protocol
            await session.close()
    except SessionEnded as exc:
        report.add("wrong", name, f"the session ended: {exc}")
        return
    report.count("honest_frames", frames)
    if protocol.divergences or protocol.bad_frames:
        report.add("wrong", name, f"{protocol.divergences} checksum mismatches and {protocol.bad_frames} bad "
                                  f"frames in {frames} frames")
    if frames == 0:
        report.add("wrong", name, "no frame at all")


# ------------------------------------------------------------------ the fuzzer


async def list_meshes(channel) -> list[MeshTarget]:
    call = channel.unary_unary("/caveclod.v1.Lod/ListMeshes", request_serializer=pb.ListMeshesRequest.SerializeToString,
                               response_deserializer=pb.ListMeshesResponse.FromString)
    reply = await call(pb.ListMeshesRequest(), timeout=60.0)
    return [MeshTarget(m.name, m.vertex_buffer_hash, m.vertices, m.base_faces,
                       (m.bounds_min.x, m.bounds_min.y, m.bounds_min.z), (m.bounds_max.x, m.bounds_max.y, m.bounds_max.z))
            for m in reply.meshes]


async def resume_ttl(channel, mesh: MeshTarget) -> int:
    """SessionInfo.resume_ttl_s of a plain session, opened and closed (the first Open also waits
    for the server's kernels: the fuzzing's deadlines start once it is ready)."""
    call = channel.stream_stream(METHOD, request_serializer=_identity,
                                 response_deserializer=pb.ServerMessage.FromString)(timeout=60.0)
    opened = pb.Open(mesh=mesh.name, cameras=1, vertex_buffer_hash=mesh.vertex_buffer_hash,
                     options=pb.RefineOptions(viewport_width=8, viewport_height=8))
    await call.write(pb.ClientMessage(open=opened).SerializeToString())
    await call.write(pb.ClientMessage(close=pb.Close()).SerializeToString())
    await call.done_writing()
    ttl = -1
    async for msg in call:
        if msg.HasField("session_info"):
            ttl = msg.session_info.resume_ttl_s
    return ttl


async def _fuzz(port: int, budget: Budget, seed: int, report: FuzzReport, concurrency: int,
                honest: bool, web_port: int | None = None) -> int:
    """The fuzzing itself, on one event loop; returns the resume TTL the server announced (or -1).
    With ``web_port``, Session cases go over WebSocket (ListMeshes and the honest sessions over gRPC)."""
    target = f"127.0.0.1:{port}"
    http = None
    if web_port is not None:
        import aiohttp
        http = aiohttp.ClientSession(connector=aiohttp.TCPConnector(limit=0))
    channels = [grpc.aio.insecure_channel(target, options=[("grpc.use_local_subchannel_pool", 1)])
                for _ in range(CHANNELS)]
    ttl = -1
    try:
        meshes = await list_meshes(channels[0])
        maker = CaseMaker(seed, meshes)
        stop = asyncio.Event()
        honest_tasks = [asyncio.ensure_future(honest_session(target, meshes[0], stop, report, cache))
                        for cache in ((False, True) if honest else ())]

        async def worker(k: int) -> None:
            while budget.more():
                case = maker.make()
                report.cases += 1
                if http is not None and case.method != "ListMeshes":
                    await run_case_ws(http, f"ws://127.0.0.1:{web_port}/v1/session", case, maker, report, seed)
                else:
                    await run_case(channels[k % CHANNELS], case, maker, report, seed)

        try:
            ttl = await resume_ttl(channels[0], meshes[0])
        except grpc.RpcError as exc:
            report.add("status" if exc.code() in BUGS else "wrong", "a plain session, to learn the resume TTL",
                       f"{exc.code().name}: {exc.details()!r}")
        try:
            await asyncio.gather(*(worker(k) for k in range(concurrency)))
        finally:
            stop.set()
            if honest_tasks:
                done, pending = await asyncio.wait(honest_tasks, timeout=30.0)
                for task in pending:
                    task.cancel()
                    report.add("hang", "honest session", "did not end within 30 s of the end of fuzzing")
                for task in done:
                    task.result()          # a bug of the fuzzer's own: raise it
    finally:
        for ch in channels:
            await ch.close()
        if http is not None:
            await http.close()
    return ttl


def fuzz_protocol(port: int, budget: Budget, seed: int, report: FuzzReport, metrics_port: int | None = None,
                  *, concurrency: int = CONCURRENCY, honest: bool = True, web_port: int | None = None) -> FuzzReport:
    """Fuzz the server on ``127.0.0.1:port`` until ``budget`` runs out (one case: one stream).

    Adds to ``report``: cases, units ``messages`` (written to gRPC),
    ``streams``, ``frames`` and ``honest_frames``, one outcome per stream
    (its status code's name) and the findings. With ``metrics_port`` (the
    server's Prometheus exporter on 127.0.0.1), checks that no session is
    left once the resume TTL has passed. With ``web_port`` (``--web-port``), the Session cases
    run over WebSocket (:func:`run_case_ws`).
    """
    t0 = time.monotonic()
    ttl = asyncio.run(_fuzz(port, budget, seed, report, concurrency, honest, web_port))
    check_health(port, report)
    if metrics_port is not None:
        check_no_sessions_left(metrics_port, ttl if ttl >= 0 else DEFAULT_TTL, report)
    report.seconds += time.monotonic() - t0
    return report


def check_health(port: int, report: FuzzReport) -> None:
    """The server must still answer health with SERVING (else a ``hang``)."""
    from grpc_health.v1 import health_pb2, health_pb2_grpc
    with grpc.insecure_channel(f"127.0.0.1:{port}") as channel:
        try:
            reply = health_pb2_grpc.HealthStub(channel).Check(health_pb2.HealthCheckRequest(service="caveclod.v1.Lod"),
                                                               timeout=10.0)
        except grpc.RpcError as exc:
            report.add("hang", "health check after fuzzing", f"{exc.code().name}: {exc.details()}")
            return
    if reply.status != health_pb2.HealthCheckResponse.SERVING:
        report.add("wrong", "health check after fuzzing", f"status {reply.status}")


def session_gauges(metrics_port: int) -> dict:
    """caveclod_sessions_active and caveclod_sessions_resumable from the server's /metrics."""
    with urllib.request.urlopen(f"http://127.0.0.1:{metrics_port}/metrics", timeout=10.0) as reply:
        text = reply.read().decode()
    out = {}
    for name in ("caveclod_sessions_active", "caveclod_sessions_resumable"):
        match = re.search(rf"^{name} (\S+)$", text, re.MULTILINE)
        out[name] = float(match.group(1)) if match else math.nan
    return out


def check_no_sessions_left(metrics_port: int, ttl: float, report: FuzzReport) -> None:
    """Every session must be gone once the resume TTL (and the reaper's round) has passed (else a ``leak``)."""
    deadline = time.monotonic() + ttl + LEAK_SLACK
    gauges = session_gauges(metrics_port)
    while any(v != 0 for v in gauges.values()) and time.monotonic() < deadline:
        time.sleep(0.2)
        gauges = session_gauges(metrics_port)
    if any(v != 0 for v in gauges.values()):
        report.add("leak", "sessions after fuzzing", f"{gauges} {ttl + LEAK_SLACK:.0f} s after the last stream "
                                                     f"ended (resume TTL {ttl} s)")


# ------------------------------------------------------------------ against `caveclod serve`


class _Drain:
    """Reads a process's output on a thread, so that its log never fills the pipe: keeps the last
    lines, the lines that start a traceback, and the first line starting with ``wanted``."""

    def __init__(self, stream, wanted: str = "", also: str = ""):
        self.tail: collections.deque = collections.deque(maxlen=40)
        self.tracebacks: list[str] = []
        self.wanted, self.found = wanted, None
        self.also, self.also_found = also, None       # a second line to keep (the viewer's port)
        self.seen = threading.Event()
        self.thread = threading.Thread(target=self._read, args=(stream,), daemon=True)
        self.thread.start()

    def _read(self, stream) -> None:
        try:
            for line in stream:
                line = line.rstrip("\n")
                self.tail.append(line)
                if self.also and self.also_found is None and line.startswith(self.also):
                    self.also_found = line
                if self.wanted and self.found is None and line.startswith(self.wanted):
                    self.found = line
                    self.seen.set()
                if ("Traceback (most recent call last)" in line or "Exception in callback" in line) \
                        and len(self.tracebacks) < 20:
                    self.tracebacks.append(line.strip())
        finally:
            self.seen.set()                # the stream ended: nobody waits for ever

    def line(self, seconds: float) -> str | None:
        """The first line starting with ``wanted``, waiting up to ``seconds``; None if none came."""
        self.seen.wait(seconds)
        return self.found

    def text(self) -> str:
        return "\n".join(self.tail)


def run_against_serve(mesh_paths, budget: Budget, seed: int, *, resume_ttl: int = 1, concurrency: int = CONCURRENCY,
                      extra_args=(), report: FuzzReport | None = None, websocket: bool = False) -> FuzzReport:
    """Start ``caveclod serve`` on ``mesh_paths`` (127.0.0.1, port 0, metrics on, a short resume TTL),
    fuzz it (:func:`fuzz_protocol`; with ``websocket``, its Session cases over ``--web-port``), and
    stop it by its pid whatever happens.

    A server that died meanwhile is a ``crash`` finding; a traceback in
    its log is a ``traceback`` finding.
    """
    from service import serve_process, stop_process
    report = report or FuzzReport("fuzzprotocol")
    proc, port = serve_process(*[str(p) for p in mesh_paths], "--resume-ttl", str(resume_ttl),
                               "--max-sessions", "1000", "--metrics-port", "0", "--metrics-host", "127.0.0.1",
                               "--announce-metrics", *(("--web-port", "0") if websocket else ()), *extra_args)
    stderr = None
    try:
        stderr = _Drain(proc.stderr)
        stdout = _Drain(proc.stdout, wanted="metrics on ", also="viewer on ")
        line = stdout.line(30.0)
        if line is None:
            raise AssertionError(f"caveclod serve did not say its metrics port; stdout: {stdout.text()!r}")
        web_port = int(stdout.also_found.rstrip("/").rsplit(":", 1)[1]) if websocket else None
        fuzz_protocol(port, budget, seed, report, metrics_port=int(line.split()[-1]), concurrency=concurrency,
                      web_port=web_port)
    finally:
        died = proc.poll()
        stop_process(proc)
        if stderr is not None:
            stderr.thread.join(5.0)
        log = stderr.text()[-1500:] if stderr is not None else ""
        if died is not None:
            report.add("crash", f"caveclod serve (seed {seed})", f"exited with {died} during fuzzing; log: {log}")
        if stderr is not None and stderr.tracebacks:
            report.add("traceback", f"caveclod serve's log (seed {seed})", f"{stderr.tracebacks}; log: {log}")
    return report


def main(argv=None) -> int:
    parser = fuzzer_arguments("Fuzz `caveclod serve` with Session streams.")
    parser.add_argument("meshes", nargs="+", help=".cvc files to serve")
    parser.add_argument("--concurrency", type=int, default=CONCURRENCY)
    parser.add_argument("--websocket", action="store_true",
                        help="send the Session cases over WebSocket (serve --web-port) instead of gRPC")
    args = parser.parse_args(argv)
    report = FuzzReport("fuzzprotocol")
    run_reported(report, run_against_serve, args.meshes, Budget(cases=args.cases, seconds=args.seconds), args.seed,
                 concurrency=args.concurrency, report=report, websocket=args.websocket)
    return finish(report, "messages", args.out)


if __name__ == "__main__":
    sys.exit(main())
