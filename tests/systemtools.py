"""Optional system tools some tests use (Debian packages that `pip install` cannot
bring): where one is missing, its tests skip and say why, so that a newcomer's
`make test` passes; `.ci/run` installs them and runs everything.

Mark such a test ``@pytest.mark.requires_tool("xvfb-run")`` (conftest.py skips
it when :func:`system_tool` finds nothing) and take the tool's path from
:func:`system_tool`. ``CAVECLOD_TESTS_WITHOUT=xvfb-run,nginx`` (or ``all``)
hides tools, to show what a machine without them does
(tests/test_system_tools.py).
"""

from __future__ import annotations

import os
import shutil

# tool: (where else it may be when not on PATH, what installs it)
TOOLS = {
    "xvfb-run": ((), "Debian's xvfb (apt-get install xvfb xauth)"),
    "nginx": (("/usr/sbin/nginx",), "Debian's nginx-light (apt-get install nginx-light)"),
    "chromium-headless-shell": ((), "Debian's chromium-headless-shell (apt-get install chromium-headless-shell)"),
    # the @grpc/grpc-js client's test (tests/test_grpcjs.py); it installs the npm packages itself
    "node": ((), "Node.js with npm (apt-get install nodejs npm)"),
}


def _hidden(name: str) -> bool:
    hide = {t.strip() for t in os.environ.get("CAVECLOD_TESTS_WITHOUT", "").split(",") if t.strip()}
    return name in hide or "all" in hide


def system_tool(name: str) -> str | None:
    """The path of tool ``name`` (a key of :data:`TOOLS`), or None where it is missing."""
    if name not in TOOLS:
        raise KeyError(f"{name!r} is not a known optional tool; add it to TOOLS in tests/systemtools.py")
    if _hidden(name):
        return None
    extra, _ = TOOLS[name]
    return shutil.which(name) or next((p for p in extra if os.access(p, os.X_OK)), None)


def skip_reason(name: str) -> str:
    return f"{name} is not installed: {TOOLS[name][1]}; .ci/run installs it"
