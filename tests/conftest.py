"""Shared pytest configuration and the renderer tests' GL context."""

import pytest


def pytest_configure(config):
    # Tests that build full-size meshes; deselect them with -m "not slow".
    config.addinivalue_line("markers", "slow: builds full-size (1024) meshes; deselect with -m 'not slow'")


@pytest.fixture(scope="module")
def gl():
    """The OpenGL context (offscreen EGL) that a test module's renderers share."""
    from caveclod.render import create_context
    ctx = create_context()
    yield ctx
    ctx.release()
