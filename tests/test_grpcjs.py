"""A Node.js client, @grpc/grpc-js with @grpc/proto-loader on protos/, against both server
transports (grpc.aio and caveclod's own HTTP/2): ListMeshes, a whole Session (RAW frames applied
and CRC-checked, five poses answered, Close ending the stream OK), calls that must fail with
their status codes, and grpc.health.v1 (tests/js/grpcjs_client.mjs does the calls and prints a
JSON summary).

Needs Node.js and npm (skipped, saying why, without them: tests/systemtools.py) and the npm
packages, which the test installs once, at pinned versions, into
``$XDG_CACHE_HOME/caveclod-tests`` (``~/.cache`` by default); where npm cannot reach its
registry the test is skipped with npm's message.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import tempfile
import time
from pathlib import Path

import pytest

from systemtools import system_tool

pytestmark = pytest.mark.requires_tool("node")

GRPC_JS = "1.14.7"
PROTO_LOADER = "0.8.1"
ROOT = Path(__file__).resolve().parents[1]
CLIENT = ROOT / "tests" / "js" / "grpcjs_client.mjs"
INSTALL_TIMEOUT = 300.0        # npm install, network included
CLIENT_TIMEOUT = 120.0         # the whole client run (its calls have 60 s deadlines)


def run_bounded(cmd: list[str], timeout: float, **kwargs) -> subprocess.CompletedProcess:
    """``cmd`` run to completion within ``timeout`` seconds, output captured; on a timeout (or
    any failure to wait) its whole process group is killed and the error raised."""
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True, **kwargs)
    try:
        out, err = proc.communicate(timeout=timeout)
    except BaseException:
        try:
            os.killpg(proc.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        proc.communicate()
        raise
    return subprocess.CompletedProcess(cmd, proc.returncode, out, err)


def _installed(modules: Path) -> bool:
    def version(package: str) -> str | None:
        try:
            return json.loads((modules / "@grpc" / package / "package.json").read_text())["version"]
        except (OSError, ValueError, KeyError):
            return None
    return version("grpc-js") == GRPC_JS and version("proto-loader") == PROTO_LOADER


def _cache_root(tmp_path_factory) -> Path:
    base = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "caveclod-tests"
    try:
        base.mkdir(parents=True, exist_ok=True)
        probe = tempfile.mkdtemp(dir=base)
        os.rmdir(probe)
        return base
    except OSError:                            # a read-only home: install for this session only
        return tmp_path_factory.mktemp("npm")


@pytest.fixture(scope="session")
def grpcjs_modules(tmp_path_factory) -> Path:
    """A node_modules holding @grpc/grpc-js and @grpc/proto-loader at the pinned versions,
    installed once (into a scratch directory, then renamed into place, so that an interrupted
    install is never taken for a whole one)."""
    final = _cache_root(tmp_path_factory) / f"grpcjs-{GRPC_JS}-proto-loader-{PROTO_LOADER}"
    if _installed(final / "node_modules"):
        return final / "node_modules"
    shutil.rmtree(final, ignore_errors=True)       # another version's leftovers, say
    npm = shutil.which("npm") or shutil.which("npm", path=str(Path(system_tool("node")).parent))
    if npm is None:
        pytest.skip("npm is not installed (Node.js is): apt-get install npm; .ci/run installs it")
    scratch = Path(tempfile.mkdtemp(dir=final.parent, prefix=".install-"))
    # a package.json of its own and --prefix: npm otherwise installs into the nearest directory
    # above that has one (and says "up to date")
    (scratch / "package.json").write_text('{"name": "caveclod-tests-grpcjs", "private": true}\n')
    cmd = [npm, "install", "--prefix", str(scratch), "--no-audit", "--no-fund", "--no-update-notifier",
           "--ignore-scripts", "--fetch-retries=1", "--fetch-timeout=30000", "--loglevel=error",
           f"@grpc/grpc-js@{GRPC_JS}", f"@grpc/proto-loader@{PROTO_LOADER}"]
    started = time.monotonic()
    try:
        r = run_bounded(cmd, INSTALL_TIMEOUT, cwd=scratch)
    except subprocess.TimeoutExpired:
        shutil.rmtree(scratch, ignore_errors=True)
        pytest.skip(f"`npm install @grpc/grpc-js@{GRPC_JS} @grpc/proto-loader@{PROTO_LOADER}` did not finish "
                    f"in {INSTALL_TIMEOUT:.0f} s (no access to the npm registry?)")
    if r.returncode != 0 or not _installed(scratch / "node_modules"):
        shutil.rmtree(scratch, ignore_errors=True)
        tail = " ".join((r.stderr or r.stdout).split())[-400:]
        pytest.skip(f"could not install @grpc/grpc-js@{GRPC_JS} and @grpc/proto-loader@{PROTO_LOADER} with npm "
                    f"(exit {r.returncode}; no access to the npm registry?): {tail}")
    print(f"npm installed @grpc/grpc-js@{GRPC_JS} @grpc/proto-loader@{PROTO_LOADER} into {final} "
          f"in {time.monotonic() - started:.1f} s")
    try:
        scratch.rename(final)
    except OSError:                            # another run got there first
        shutil.rmtree(scratch, ignore_errors=True)
        if not _installed(final / "node_modules"):
            raise
    return final / "node_modules"


def run_client(node_modules: Path, port: int, mesh: str = "terrain") -> dict:
    """grpcjs_client.mjs against 127.0.0.1:port: its JSON summary (stderr in any failure)."""
    env = {**os.environ, "NODE_PATH": str(node_modules)}
    for var in ("GRPC_TRACE", "GRPC_VERBOSITY", "NODE_OPTIONS"):
        env.pop(var, None)
    r = run_bounded([system_tool("node"), str(CLIENT), f"127.0.0.1:{port}", mesh], CLIENT_TIMEOUT, cwd=ROOT, env=env)
    lines = r.stdout.strip().splitlines()
    assert lines, f"the client printed nothing (exit {r.returncode}): {r.stderr[-3000:]}"
    summary = json.loads(lines[-1])
    assert summary["errors"] == [], f"{summary['errors']}\n{json.dumps(summary)[:3000]}\n{r.stderr[-2000:]}"
    assert r.returncode == 0, r.stderr[-3000:]
    return summary


@pytest.mark.parametrize("transport", ["grpc", "h2"])
def test_a_grpcjs_client_runs_a_session(make_server, grpcjs_modules, transport):
    server = make_server(transport=transport)
    s = run_client(grpcjs_modules, server.port)
    assert s["grpc_js"] == GRPC_JS

    [mesh] = s["list_meshes"]
    assert mesh["name"] == "terrain" and mesh["faces"] == 4608 and mesh["vertices"] > 0
    assert mesh["bounds_max"]["z"] > mesh["bounds_min"]["z"]

    sess = s["session"]
    assert sess["status"] == "OK" and sess["details"] == "" and sess["close_sent"]
    assert sess["session_info"] and sess["frame_encoding"] == "FRAME_ENCODING_RAW"
    # the whole vertex buffer, in order, matching SessionInfo.vertex_payload_crc32
    assert sess["vertex_chunks"] >= 1 and sess["vertex_bytes"] == sess["vertex_payload_bytes"] > 0
    assert sess["vertex_crc_ok"] is True
    # every pose answered; every frame applied, CRC-checked and acked
    assert sess["poses_sent"] == 5 and sess["poses_answered"] == [1, 2, 3, 4, 5] and sess["last_pose_seq"] == 5
    # Frame 1 is the keyframe; it answers pose 1 too when that pose came before the frame was made
    # (seen once with the machine loaded): five frames at least, not six.
    assert sess["frames"] >= 5 and sess["acks"] == sess["frames"] and sess["keyframes"] >= 1
    assert sess["crc_mismatches"] == 0 and sess["crc_checks"] >= sess["frames"]
    assert sess["triangles"] > 0

    errors = s["error_calls"]
    assert errors["session_unknown_mesh"]["status"] == "NOT_FOUND"
    assert "no-such-mesh" in errors["session_unknown_mesh"]["details"]
    assert errors["session_unknown_mesh"]["messages"] == []
    assert errors["session_pose_first"]["status"] == "INVALID_ARGUMENT"
    assert "Open" in errors["session_pose_first"]["details"]
    assert errors["unknown_method"]["status"] == "UNIMPLEMENTED"
    assert errors["health_unknown_service"]["status"] == "NOT_FOUND"

    assert s["health"] == {"(server)": "SERVING", "caveclod.v1.Lod": "SERVING"}
