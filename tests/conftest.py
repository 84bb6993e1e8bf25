"""Shared pytest configuration, the service tests' fixtures and the renderer tests' GL context."""

from __future__ import annotations

import gc

import pytest


def pytest_configure(config):
    # `caveclod serve` processes the tests start remember the meshes they checked
    # (--checked-dir): in a directory of this run, not the user's cache.
    import os
    import tempfile
    if not os.environ.get("CAVECLOD_CHECKED_DIR"):
        config._caveclod_checked = os.environ["CAVECLOD_CHECKED_DIR"] = tempfile.mkdtemp(prefix="caveclod-checked-")
    # Clients (here and in the processes the tests start) cache vertex buffers in a directory
    # of this run, not the user's cache, where an entry of another checkout's build must not
    # decide a test.
    if not os.environ.get("CAVECLOD_CACHE_DIR"):
        config._caveclod_vertex_cache = os.environ["CAVECLOD_CACHE_DIR"] = tempfile.mkdtemp(
            prefix="caveclod-vertex-buffers-")
    # Tests that build full-size meshes; deselect them with -m "not slow".
    config.addinivalue_line("markers", "slow: builds full-size (1024) meshes; deselect with -m 'not slow'")
    config.addinivalue_line("markers", "requires_tool(name): needs an optional system tool (tests/systemtools.py); "
                                       "skipped, with the reason, where it is missing")


def pytest_unconfigure(config):
    import shutil
    if getattr(config, "_caveclod_checked", None):
        shutil.rmtree(config._caveclod_checked, ignore_errors=True)
    if getattr(config, "_caveclod_vertex_cache", None):
        shutil.rmtree(config._caveclod_vertex_cache, ignore_errors=True)


def pytest_runtest_setup(item):
    from systemtools import skip_reason, system_tool
    for mark in item.iter_markers("requires_tool"):
        if system_tool(mark.args[0]) is None:
            pytest.skip(skip_reason(mark.args[0]))


@pytest.fixture(scope="session")
def terrain_path(tmp_path_factory):
    """A small built-in terrain (48 x 48 cells, 4,608 triangles) saved as terrain.cvc."""
    import caveclod
    path = tmp_path_factory.mktemp("meshes") / "terrain.cvc"
    caveclod.build("default", size=48).save(path)
    return path


# The service's test modules run once per server transport: grpc.aio, and
# caveclod's own HTTP/2 (caveclod serve --transport h2), which must behave alike.
BOTH_TRANSPORTS = {"test_service_session", "test_service_errors", "test_service_acks", "test_service_ops",
                   "test_service_opstream", "test_service_cache", "test_service_vertexpack", "test_service_resilience",
                   "test_client_failover", "test_fuzz_protocol", "test_web"}


def pytest_generate_tests(metafunc):
    if "server_transport" in metafunc.fixturenames and metafunc.module.__name__ in BOTH_TRANSPORTS:
        metafunc.parametrize("server_transport", ["grpc", "h2"], indirect=True)


@pytest.fixture
def server_transport(request):
    """The server transport of make_server: "grpc" or "h2" (both, for the modules in BOTH_TRANSPORTS)."""
    return getattr(request, "param", "grpc")


@pytest.fixture
def make_server(terrain_path, server_transport):
    """``make_server(**config)`` starts an in-process LodServer on 127.0.0.1:0 serving
    the small terrain (ready: kernels loaded); every one is stopped after the test."""
    from caveclod.server import LodServer, ServerConfig
    servers = []

    def make(meshes=None, **overrides):
        config = ServerConfig(meshes=[str(p) for p in (meshes or [terrain_path])],
                              # TLS is grpc.aio's only (caveclod's own HTTP/2 serves plaintext)
                              **{"host": "127.0.0.1", "port": 0,
                                 "transport": "grpc" if overrides.get("tls_cert") else server_transport, **overrides})
        server = LodServer(config).start()
        servers.append(server)
        assert server.sessions.ready.wait(60), "the refinement kernels did not load"
        return server

    try:
        yield make
    finally:
        for s in servers:
            s.stop(grace=0)
        # A stopped grpc.aio server keeps its descriptors (about 20) until the
        # garbage collector breaks its reference cycles; collect now so that
        # a long session never runs out of them.
        gc.collect()


@pytest.fixture
def server(make_server):
    """A LodServer with the default options."""
    return make_server()


@pytest.fixture(scope="module")
def gl():
    """The OpenGL context (offscreen EGL) that a test module's renderers share."""
    from caveclod.render import create_context
    ctx = create_context()
    yield ctx
    ctx.release()
