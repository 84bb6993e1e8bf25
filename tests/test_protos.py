"""The wire protocol (protos/) and the container file (deploy/), checked
without a server, a network or a Docker daemon.

The proto is compiled with ``grpc_tools.protoc`` into a temporary directory
and its generated module loaded by path (protoc names it
``caveclod.v1.caveclod_pb2``, which would resolve inside the core package).
The Dockerfile checks are plain text.
"""

from __future__ import annotations

import importlib.util
import json
import re
import shlex
import sys
import zlib
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parent.parent
PROTO_ROOT = ROOT / "protos"
PROTO = "caveclod/v1/caveclod.proto"
DOCKERFILE = ROOT / "deploy" / "Dockerfile"
DOCKERIGNORE = ROOT / ".dockerignore"
MiB = 1 << 20


# -- compiling ------------------------------------------------------------------

@pytest.fixture(scope="module")
def compiled(tmp_path_factory):
    """(generated pb2 module, FileDescriptorProto with comments, output dir)."""
    pytest.importorskip("grpc_tools.protoc", reason="grpcio-tools is not installed; "
                        "pip install grpcio-tools (it belongs in the 'test' extra)")
    from google.protobuf import descriptor_pb2
    from grpc_tools import protoc

    out = tmp_path_factory.mktemp("proto_gen")
    ds = out / "caveclod.desc"
    argv = ["grpc_tools.protoc", f"-I{PROTO_ROOT}", f"--python_out={out}", f"--grpc_python_out={out}",
            "--include_source_info", f"--descriptor_set_out={ds}", PROTO]
    assert protoc.main(argv) == 0, f"protoc failed on {PROTO}; run: python -m {' '.join(argv)}"
    files = descriptor_pb2.FileDescriptorSet.FromString(ds.read_bytes()).file
    assert [f.name for f in files] == [PROTO]

    path = out / "caveclod" / "v1" / "caveclod_pb2.py"
    spec = importlib.util.spec_from_file_location("caveclod_wire_v1_pb2", path)
    pb = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = pb
    spec.loader.exec_module(pb)
    return pb, files[0], out


def test_proto_package_and_service(compiled):
    pb, fd, out = compiled
    assert fd.package == "caveclod.v1"
    assert fd.syntax == "proto3"
    assert list(fd.dependency) == []          # self-contained: no imports to vendor
    (service,) = fd.service
    assert service.name == "Lod"
    methods = {m.name: m for m in service.method}
    assert set(methods) == {"Session", "ListMeshes"}
    session = methods["Session"]
    assert session.client_streaming and session.server_streaming
    assert session.input_type == ".caveclod.v1.ClientMessage"
    assert session.output_type == ".caveclod.v1.ServerMessage"
    assert not (methods["ListMeshes"].client_streaming or methods["ListMeshes"].server_streaming)
    grpc_code = (out / "caveclod" / "v1" / "caveclod_pb2_grpc.py").read_text()
    for name in ("class LodStub", "class LodServicer", "def add_LodServicer_to_server"):
        assert name in grpc_code


def test_client_and_server_messages_are_oneofs(compiled):
    pb, _, _ = compiled
    client = {f.name for f in pb.ClientMessage.DESCRIPTOR.oneofs_by_name["kind"].fields}
    server = {f.name for f in pb.ServerMessage.DESCRIPTOR.oneofs_by_name["kind"].fields}
    assert client == {"open", "pose", "ack", "keyframe_request", "close"}
    assert server == {"session_info", "vertex_chunk", "frame", "status"}     # status: WebSocket only


# -- round trips ----------------------------------------------------------------

def _apply(buf: np.ndarray, d) -> np.ndarray:
    """Apply a SurfaceDelta message to a (k, 3) uint32 buffer, as a client does."""
    slots = np.frombuffer(d.slots, dtype="<u4")
    tris = np.frombuffer(d.tris, dtype="<u4").reshape(-1, 3)
    if len(slots) == 0:
        slots = np.arange(d.first_slot, d.first_slot + len(tris), dtype=np.uint32)
    assert len(slots) == len(tris)
    new = np.zeros((d.count, 3), np.uint32)
    keep = min(len(buf), d.count)
    new[:keep] = buf[:keep]
    new[slots] = tris
    return new


def _crc(buf: np.ndarray) -> int:
    return zlib.crc32(np.ascontiguousarray(buf, dtype="<u4"))


def test_frame_round_trip_with_numpy_arrays(compiled):
    pb, _, _ = compiled
    rng = np.random.default_rng(3)
    old = rng.integers(0, 50_000, size=(1000, 3), dtype=np.uint32)
    # A delta: overwrite some slots, drop 10 triangles (holes refilled from the end).
    slots = np.sort(rng.choice(990, size=120, replace=False)).astype(np.uint32)
    tris = rng.integers(0, 50_000, size=(120, 3), dtype=np.uint32)
    expect = old[:990].copy()
    expect[slots] = tris
    # A keyframe of another material: consecutive slots, no slot array.
    full = rng.integers(0, 50_000, size=(300, 3), dtype=np.uint32)

    frame = pb.Frame(frame_seq=7, pose_seq=41, poses_superseded=2)
    cam = frame.cameras.add(camera=1, pose_seq=41, keyframe=False)
    cam.surfaces.add(material=2, count=990, slots=slots.astype("<u4").tobytes(),
                     tris=tris.astype("<u4").tobytes(), crc32=_crc(expect))
    cam.surfaces.add(material=3, count=300, first_slot=0, tris=full.astype("<u4").tobytes(), crc32=_crc(full))
    cam.surfaces.add(material=0, count=0, crc32=0)          # emptied
    cam.stats.splits, cam.stats.collapses, cam.stats.update_us = 40, 55, 812
    cam.stats.active_faces, cam.stats.pose_age_us = 1290, 2400

    wire = pb.ServerMessage(frame=frame).SerializeToString()
    back = pb.ServerMessage.FromString(wire)
    assert back.WhichOneof("kind") == "frame"
    assert back == pb.ServerMessage(frame=frame)
    (c,) = back.frame.cameras
    a, b, z = c.surfaces
    np.testing.assert_array_equal(np.frombuffer(a.slots, dtype="<u4"), slots)
    np.testing.assert_array_equal(np.frombuffer(a.tris, dtype="<u4").reshape(-1, 3), tris)
    np.testing.assert_array_equal(_apply(old, a), expect)
    np.testing.assert_array_equal(_apply(np.zeros((0, 3), np.uint32), b), full)
    assert _apply(old, z).shape == (0, 3)
    for d, buf in ((a, old), (b, np.zeros((0, 3), np.uint32)), (z, old)):
        assert d.HasField("crc32")
        assert d.crc32 == _crc(_apply(buf, d))
    assert zlib.crc32(b"") == 0                              # an empty buffer's checksum
    assert c.stats.update_us == 812 and back.frame.poses_superseded == 2
    # Arrays are bytes: a 120-triangle delta costs about 16 bytes a triangle.
    assert len(wire) < 120 * 16 + 300 * 12 + 200


def test_client_messages_round_trip_and_defaults(compiled):
    pb, _, _ = compiled
    opened = pb.ClientMessage(open=pb.Open(
        mesh="terrain", cameras=2, options=pb.RefineOptions(viewport_width=1280, viewport_height=720)))
    back = pb.ClientMessage.FromString(opened.SerializeToString()).open
    # Unset optional options are distinguishable from zero: the server fills
    # in its defaults (tolerance 1 px, fov 60 degrees, culling on).
    for name in ("fov_y_deg", "tolerance_px", "cull", "backface", "max_ops", "max_faces"):
        assert not back.options.HasField(name)
    assert back.resume_token == "" and back.vertex_buffer_hash == ""

    pose = pb.ClientMessage(pose=pb.CameraPose(camera=1, pose_seq=9, eye=pb.Vec3(x=1.5, y=-2.0, z=300.25),
                                               target=pb.Vec3(x=10, y=10), up=pb.Vec3(z=1)))
    p = pb.ClientMessage.FromString(pose.SerializeToString()).pose
    assert (p.eye.x, p.eye.y, p.eye.z, p.up.z, p.pose_seq) == (1.5, -2.0, 300.25, 1.0, 9)

    ask = pb.ClientMessage(keyframe_request=pb.KeyframeRequest(
        reason=pb.KEYFRAME_REASON_CHECKSUM_MISMATCH, frame_seq=12))
    k = pb.ClientMessage.FromString(ask.SerializeToString()).keyframe_request
    assert not k.HasField("camera")                          # unset: every camera
    assert k.reason == pb.KEYFRAME_REASON_CHECKSUM_MISMATCH


def test_vertex_buffer_in_planar_chunks(compiled):
    pb, _, _ = compiled
    rng = np.random.default_rng(5)
    d = 40_000
    blocks = {"POSITION": rng.normal(size=(d, 3)).astype("<f4"), "NORMAL": rng.normal(size=(d, 3)).astype("<f4"),
              "TEXCOORD": rng.random((d, 2)).astype("<f4"),
              "COLOR": rng.integers(0, 256, size=(d, 4), dtype=np.uint8)}
    fmt = pb.VertexFormat(layout=pb.VERTEX_LAYOUT_PLANAR, vertex_count=d)
    offset = 0
    for name, a in blocks.items():
        fmt.attributes.add(semantic=getattr(pb, f"ATTRIBUTE_SEMANTIC_{name}"),
                           type=pb.SCALAR_TYPE_UINT8 if a.dtype == np.uint8 else pb.SCALAR_TYPE_FLOAT32,
                           components=a.shape[1], normalized=a.dtype == np.uint8,
                           offset=offset, stride=a.itemsize * a.shape[1])
        offset += a.nbytes
    payload = b"".join(a.tobytes() for a in blocks.values())
    fmt.payload_bytes = len(payload)
    info = pb.SessionInfo(vertex_format=fmt, vertex_payload_crc32=zlib.crc32(payload), max_chunk_bytes=MiB)
    chunks = [pb.ServerMessage(vertex_chunk=pb.VertexChunk(offset=o, total=len(payload), data=payload[o:o + MiB]))
              .SerializeToString() for o in range(0, len(payload), MiB)]
    assert len(chunks) == 2

    info = pb.SessionInfo.FromString(info.SerializeToString())
    got = bytearray()
    for raw in chunks:
        c = pb.ServerMessage.FromString(raw).vertex_chunk
        assert c.offset == len(got) and len(c.data) <= info.max_chunk_bytes
        got += c.data
    assert len(got) == c.total == info.vertex_format.payload_bytes
    assert zlib.crc32(got) == info.vertex_payload_crc32
    dtypes = {pb.SCALAR_TYPE_FLOAT32: "<f4", pb.SCALAR_TYPE_UINT8: "u1"}
    for attr, a in zip(info.vertex_format.attributes, blocks.values()):
        view = np.frombuffer(got, dtype=dtypes[attr.type], count=attr.components * d,
                             offset=attr.offset).reshape(d, attr.components)
        np.testing.assert_array_equal(view, a)


# -- the proto's own rules ----------------------------------------------------------

def _commented(fd):
    """(path in the file, element name, needs a leading comment) for every element."""
    def message(m, path, prefix):
        yield path, f"message {prefix}{m.name}", True
        for i, f in enumerate(m.field):
            yield path + [2, i], f"field {prefix}{m.name}.{f.name}", False
        synthetic = {f.oneof_index for f in m.field if f.proto3_optional}   # made by `optional`
        for i, o in enumerate(m.oneof_decl):
            if i not in synthetic:
                yield path + [8, i], f"oneof {prefix}{m.name}.{o.name}", False
        for i, n in enumerate(m.nested_type):
            if not n.options.map_entry:
                yield from message(n, path + [3, i], f"{prefix}{m.name}.")
        for i, e in enumerate(m.enum_type):
            yield from enum(e, path + [4, i], f"{prefix}{m.name}.")

    def enum(e, path, prefix):
        yield path, f"enum {prefix}{e.name}", True
        for i, v in enumerate(e.value):
            yield path + [2, i], f"enum value {v.name}", False

    for i, m in enumerate(fd.message_type):
        yield from message(m, [4, i], "")
    for i, e in enumerate(fd.enum_type):
        yield from enum(e, [5, i], "")
    for i, s in enumerate(fd.service):
        yield [6, i], f"service {s.name}", True
        for j, m in enumerate(s.method):
            yield [6, i, 2, j], f"rpc {s.name}.{m.name}", True


def test_every_element_has_a_comment(compiled):
    _, fd, _ = compiled
    where = {tuple(loc.path): loc for loc in fd.source_code_info.location}
    missing = []
    for path, name, leading in _commented(fd):
        loc = where.get(tuple(path))
        text = "" if loc is None else loc.leading_comments.strip() or ("" if leading else loc.trailing_comments.strip())
        if not text:
            missing.append(name)
    assert not missing, f"{PROTO}: add a leading comment to: {', '.join(missing)}"
    assert len(fd.message_type) >= 20


def test_arrays_travel_as_bytes(compiled):
    _, fd, _ = compiled
    from google.protobuf.descriptor_pb2 import FieldDescriptorProto as F
    repeated_scalars = [f"{m.name}.{f.name}" for m in fd.message_type for f in m.field
                        if f.label == F.LABEL_REPEATED and f.type != F.TYPE_MESSAGE]
    assert not repeated_scalars, f"arrays must be little-endian bytes fields, not repeated scalars: {repeated_scalars}"
    delta = next(m for m in fd.message_type if m.name == "SurfaceDelta")
    types = {f.name: f.type for f in delta.field}
    assert types["slots"] == types["tris"] == F.TYPE_BYTES
    chunk = next(m for m in fd.message_type if m.name == "VertexChunk")
    assert {f.name: f.type for f in chunk.field}["data"] == F.TYPE_BYTES


def test_enums_start_unspecified(compiled):
    _, fd, _ = compiled
    for e in fd.enum_type:
        prefix = re.sub(r"(?<!^)(?=[A-Z])", "_", e.name).upper()
        assert e.value[0].number == 0 and e.value[0].name == f"{prefix}_UNSPECIFIED", e.name
        assert all(v.name.startswith(prefix + "_") for v in e.value), e.name


def test_the_comments_settle_what_other_languages_must_know(compiled):
    """Each rule a client in another language needs is written in the proto itself."""
    _, fd, _ = compiled
    where = {tuple(loc.path): loc.leading_comments + loc.trailing_comments for loc in fd.source_code_info.location}
    text = (PROTO_ROOT / PROTO).read_text()
    session = " ".join(where[(6, 0, 2, 0)].split())
    for rule in ("Frame 1 is sent right after SessionInfo and the vertex chunks, without waiting for a pose",
                 "at most one refinement update per camera per frame",
                 "exactly one update's operations",
                 "counts toward the server's session limit",
                 "caveclod_sessions_active counts sessions with a connected stream"):
        assert rule in session, f"Lod.Session's comment must say: {rule}"
    flat = " ".join(w for w in text.split() if w != "//")
    for rule in ("protos/grpc/health/v1/health.proto", "UNAUTHENTICATED", "authorization: Bearer <token>",
                 "v1 servers always set it, so it needs no presence",
                 "empties every index buffer of the camera (count 0)",
                 "resumable ones included",
                 # cache mode: what a client in another language must do
                 "no VertexChunk is sent",
                 "the sum, modulo 2^32, over the slots that hold a vertex, of the CRC-32",
                 "in cache mode every vertex slot of the camera (no slot holds a vertex)",
                 "applied before the surfaces of this same entry",
                 "raises the camera's tolerance by factors of 1.25 until the vertices fit"):
        assert rule in flat, f"{PROTO} must say: {rule}"


# -- deploy/Dockerfile (pure text) -------------------------------------------------

def _instructions(text: str) -> list[tuple[str, str]]:
    """(INSTRUCTION, arguments) of a Dockerfile: comments dropped, continuations joined."""
    out, pending = [], ""
    for line in text.splitlines():
        stripped = line.strip()
        if not pending and (not stripped or stripped.startswith("#")):
            continue
        if pending and stripped.startswith("#"):       # comment lines inside a continuation
            continue
        if stripped.endswith("\\"):
            pending += stripped[:-1] + " "
            continue
        full = pending + stripped
        pending = ""
        word, _, rest = full.partition(" ")
        out.append((word.upper(), rest.strip()))
    assert not pending, "Dockerfile ends inside a line continuation"
    return out


@pytest.fixture(scope="module")
def dockerfile():
    return _instructions(DOCKERFILE.read_text())


def test_dockerfile_stages_and_base_images(dockerfile):
    known = {"FROM", "RUN", "CMD", "LABEL", "EXPOSE", "ENV", "ADD", "COPY", "ENTRYPOINT", "VOLUME", "USER",
             "WORKDIR", "ARG", "ONBUILD", "STOPSIGNAL", "HEALTHCHECK", "SHELL"}
    assert {word for word, _ in dockerfile} <= known
    froms = [args.split() for word, args in dockerfile if word == "FROM"]
    assert len(froms) >= 2, "multi-stage: a build stage and a runtime stage"
    stages = set()
    for args in froms:
        image = args[0]
        if image in stages:                             # FROM an earlier stage
            continue
        assert image.startswith("python:3.11-slim"), f"base image {image} is not python:3.11-slim"
        name, _, tag = image.partition("@")[0].partition(":")
        assert tag and tag != "latest", f"{image}: pin a tag, never latest"
        if len(args) >= 3 and args[1].upper() == "AS":
            stages.add(args[2])
    copies_from = [a for w, a in dockerfile if w == "COPY" and a.startswith("--from=")]
    assert copies_from and all(a.split()[0].split("=", 1)[1] in stages for a in copies_from)


def test_dockerfile_installs_the_repo_and_runs_caveclod_unprivileged(dockerfile):
    runs = " ".join(args for word, args in dockerfile if word == "RUN")
    assert re.search(r"pip install\b[^&;]*\s\"?\.(\[server\])?\"?(\s|$)", runs), \
        "installs the package from the repo: pip install . (or '.[server]')"
    users = [args for word, args in dockerfile if word == "USER"]
    assert users, "the image must set a USER"
    user = users[-1].split(":")[0]
    assert user not in ("root", "0"), f"final USER is {users[-1]}; run as a non-root user"
    # The runtime stage (after the last FROM) must switch user before the entrypoint.
    last_from = max(i for i, (w, _) in enumerate(dockerfile) if w == "FROM")
    assert any(w == "USER" for w, _ in dockerfile[last_from:])
    (entry,) = [args for word, args in dockerfile if word == "ENTRYPOINT"]
    assert entry.startswith("["), "ENTRYPOINT in exec form, so signals reach caveclod"
    assert json.loads(entry)[0] == "caveclod"
    env = " ".join(args for word, args in dockerfile if word == "ENV")
    assert "NUMBA_CACHE_DIR=" in env
    assert "caveclod build" in runs, "numba kernels are compiled at image build time"


def test_dockerfile_fetches_nothing_remote_by_add_and_no_latest(dockerfile):
    for word, args in dockerfile:
        if word == "ADD":
            assert not re.search(r"\b(https?|git)://|git@", args), f"ADD of a remote URL: {args}"
        assert not re.search(r":latest\b", args), f"{word} {args}: no latest tags"
        if word in ("COPY", "ADD"):
            assert ".." not in shlex.split(args), "copies stay inside the build context"


def test_dockerignore_keeps_the_context_small():
    lines = {line.strip().rstrip("/") for line in DOCKERIGNORE.read_text().splitlines()
             if line.strip() and not line.startswith("#")}
    for needed in (".git", ".venv", "out", "**/__pycache__", ".pytest_cache", ".hypothesis"):
        assert needed in lines, f".dockerignore should exclude {needed}"
    for kept in ("caveclod", "pyproject.toml", "README.md"):
        assert kept not in lines, f".dockerignore must not exclude {kept}: the image installs from it"
