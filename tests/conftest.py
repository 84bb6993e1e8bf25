"""Shared pytest configuration."""


def pytest_configure(config):
    # Tests that build full-size meshes; deselect them with -m "not slow".
    config.addinivalue_line("markers", "slow: builds full-size (1024) meshes; deselect with -m 'not slow'")
