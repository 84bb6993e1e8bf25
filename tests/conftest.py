"""Shared pytest configuration, the service tests' fixtures and the renderer tests' GL context."""

from __future__ import annotations

import gc

import pytest


def pytest_configure(config):
    # Tests that build full-size meshes; deselect them with -m "not slow".
    config.addinivalue_line("markers", "slow: builds full-size (1024) meshes; deselect with -m 'not slow'")
    config.addinivalue_line("markers", "requires_tool(name): needs an optional system tool (tests/systemtools.py); "
                                       "skipped, with the reason, where it is missing")


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


@pytest.fixture
def make_server(terrain_path):
    """``make_server(**config)`` starts an in-process LodServer on 127.0.0.1:0 serving
    the small terrain (ready: kernels loaded); every one is stopped after the test."""
    from caveclod.server import LodServer, ServerConfig
    servers = []

    def make(meshes=None, **overrides):
        config = ServerConfig(meshes=[str(p) for p in (meshes or [terrain_path])],
                              **{"host": "127.0.0.1", "port": 0, **overrides})
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
