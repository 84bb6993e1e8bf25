"""The thin client needs numpy, grpcio and protobuf only.

A full session runs in a subprocess whose imports are watched by a
``sys.meta_path`` finder: anything outside the standard library, numpy,
grpc, google.protobuf and caveclod's client-side modules is refused, and
so are the core's build and refinement modules and the server. The server
runs in a process of its own (``caveclod serve``).
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from service import ROOT, serve_process, stop_process

CLIENT = r'''
import sys

# typing_extensions: grpcio's own dependency (grpc.aio imports it)
ALLOWED = set(sys.stdlib_module_names) | {"numpy", "grpc", "google", "caveclod", "typing_extensions"}
REFUSED = ("caveclod.server", "caveclod.api", "caveclod.builder", "caveclod.refine", "caveclod.kernels",
           "caveclod.staticmesh", "caveclod.demo", "numba", "trimesh", "llvmlite")

class Refuse:
    def find_spec(self, name, path=None, target=None):
        top = name.partition(".")[0]
        if top not in ALLOWED or any(name == r or name.startswith(r + ".") for r in REFUSED):
            raise ImportError(f"the thin client imported {name}")
        return None

sys.meta_path.insert(0, Refuse())

from caveclod.client import Client
from caveclod.paths import flyover

with Client(sys.argv[1], cache_dir=sys.argv[2]) as client:
    with client.session("terrain", cameras=2, width=640, height=360) as s:
        lo, hi = s.vertex_buffer.positions.min(0), s.vertex_buffer.positions.max(0)
        for i in range(20):
            for c in range(2):
                seq = s.send_pose(c, *flyover(lo, hi, c, i / 10))
            while s.next_frame(timeout=10).pose_seq < seq:
                pass
        assert s.protocol.divergences == 0
        faces = sum(len(t) for t in s.triangles(0).values())
import asyncio
from caveclod.client.aio import AsyncClient
async def main():
    async with AsyncClient(sys.argv[1], cache_dir=sys.argv[2]) as client:
        s = await client.session("terrain", width=64, height=64)
        assert (await s.next_frame(timeout=10)).frame_seq == 1
        await s.close()
asyncio.run(main())
import caveclod.client.loadtest
leaked = sorted(m for m in sys.modules if m.partition(".")[0] in ("numba", "trimesh", "llvmlite")
                or m.startswith(REFUSED))
print("faces", faces, "leaked", leaked)
'''


def test_a_full_session_imports_nothing_but_numpy_grpc_and_protobuf(terrain_path, tmp_path):
    server, port = serve_process(str(terrain_path))
    try:
        proc = subprocess.run([sys.executable, "-c", CLIENT, f"127.0.0.1:{port}", str(tmp_path)],
                              capture_output=True, text=True, cwd=ROOT, timeout=120)
    finally:
        stop_process(server)
    assert proc.returncode == 0, proc.stderr[-3000:]
    words = proc.stdout.split()
    assert words[0] == "faces" and int(words[1]) > 0
    assert proc.stdout.strip().endswith("leaked []")


def test_the_base_install_is_the_client():
    tomllib = pytest.importorskip("tomllib")          # Python 3.11+
    project = tomllib.loads(Path(ROOT, "pyproject.toml").read_text())["project"]
    names = {d.split(">")[0].split("=")[0].split("<")[0].strip() for d in project["dependencies"]}
    assert names == {"numpy", "grpcio", "protobuf"}
    extras = project["optional-dependencies"]
    assert extras["client"] == []
    server = " ".join(extras["server"])
    for needed in ("caveclod[build]", "grpcio-health-checking", "grpcio-reflection", "prometheus-client"):
        assert needed in server
    assert "server" in " ".join(extras["all"]) and "build" in " ".join(extras["all"])
