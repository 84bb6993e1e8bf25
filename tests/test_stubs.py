"""The committed caveclod.v1 stubs are current, and the shipped health proto is
the one the server runs.

The stubs in ``caveclod/v1/`` are generated from ``protos/`` by ``make
protos``. This test generates them again into a temporary directory and
compares: message code by its descriptor (what goes on the wire), the
``.pyi`` and gRPC code by text with generator version stamps left out, so
that nothing but a real change of the .proto fails it.
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
STUBS = ROOT / "caveclod" / "v1"
COMMAND = ("python -m grpc_tools.protoc -I protos --python_out=. --pyi_out=. --grpc_python_out=. "
           "caveclod/v1/caveclod.proto   (or: make protos)")
VERSION_STAMPS = [
    (re.compile(r"^# Protobuf Python Version: .*$", re.M), "# Protobuf Python Version: X"),
    (re.compile(r"ValidateProtobufRuntimeVersion\([^)]*\)", re.S), "ValidateProtobufRuntimeVersion(X)"),
    (re.compile(r"^GRPC_GENERATED_VERSION = .*$", re.M), "GRPC_GENERATED_VERSION = X"),
]


def _normalized(text: str) -> str:
    for pattern, repl in VERSION_STAMPS:
        text = pattern.sub(repl, text)
    return text


def _descriptor(pb2_source: str):
    from google.protobuf import descriptor_pb2
    blob = re.search(r"AddSerializedFile\((b'.*?')\)", pb2_source, re.S).group(1)
    return descriptor_pb2.FileDescriptorProto.FromString(ast.literal_eval(blob))   # the bytes literal protoc wrote


@pytest.fixture(scope="module")
def generated(tmp_path_factory):
    protoc = pytest.importorskip("grpc_tools.protoc", reason="grpcio-tools is in the 'test' extra")
    out = tmp_path_factory.mktemp("stubs")
    argv = ["grpc_tools.protoc", f"-I{ROOT / 'protos'}", f"--python_out={out}", f"--pyi_out={out}",
            f"--grpc_python_out={out}", "caveclod/v1/caveclod.proto"]
    assert protoc.main(argv) == 0
    return out / "caveclod" / "v1"


def test_committed_stubs_match_the_proto(generated):
    stale = []
    for name in ("caveclod_pb2.pyi", "caveclod_pb2_grpc.py"):
        if _normalized((generated / name).read_text()) != _normalized((STUBS / name).read_text()):
            stale.append(name)
    if _descriptor((generated / "caveclod_pb2.py").read_text()) != _descriptor((STUBS / "caveclod_pb2.py").read_text()):
        stale.append("caveclod_pb2.py")
    assert not stale, f"caveclod/v1/{', '.join(stale)} are stale; regenerate them from the repository root: {COMMAND}"


def test_stubs_import_as_caveclod_v1_with_the_pinned_runtimes():
    """The runtime version checks in the stubs pass with the pyproject lower bounds."""
    from caveclod.v1 import caveclod_pb2, caveclod_pb2_grpc
    assert caveclod_pb2.DESCRIPTOR.package == "caveclod.v1"
    assert hasattr(caveclod_pb2_grpc, "LodStub")
    pb2 = (STUBS / "caveclod_pb2.py").read_text()
    major, minor, patch = (int(x) for x in re.search(
        r"Domain\.PUBLIC,\s*(\d+),\s*(\d+),\s*(\d+),", pb2).groups())
    grpc_version = re.search(r"GRPC_GENERATED_VERSION = '([\d.]+)'", (STUBS / "caveclod_pb2_grpc.py").read_text())[1]
    pyproject = (ROOT / "pyproject.toml").read_text()
    assert f'"protobuf>={major}.{minor}.{patch}' in pyproject, "pin protobuf at the stubs' gencode version"
    assert f'"grpcio>={grpc_version}' in pyproject, "pin grpcio at the stubs' generator version"


def test_the_shipped_health_proto_is_the_one_the_server_runs(tmp_path):
    """grpcio-health-checking ships no .proto, only its compiled descriptor: compare with that."""
    protoc = pytest.importorskip("grpc_tools.protoc")
    from google.protobuf import descriptor_pb2
    from grpc_health.v1 import health_pb2
    assert protoc.main(["grpc_tools.protoc", f"-I{ROOT / 'protos'}", f"--python_out={tmp_path}",
                        "grpc/health/v1/health.proto"]) == 0
    ours = _descriptor((tmp_path / "grpc" / "health" / "v1" / "health_pb2.py").read_text())
    theirs = descriptor_pb2.FileDescriptorProto.FromString(health_pb2.DESCRIPTOR.serialized_pb)
    ours.name = theirs.name                  # the package keeps it under grpc_health/v1/
    assert ours == theirs, "protos/grpc/health/v1/health.proto differs from grpcio-health-checking's"
    assert "grpc/health/v1/health.proto" in (ROOT / "protos" / "caveclod" / "v1" / "caveclod.proto").read_text()
