"""A machine without the optional system tools (xvfb, nginx, Chromium, Node.js) passes `make test`:
the tests that need one skip and say why (issue 17's finding 6: a test called
xvfb-run with no skip, and CI, which installs it, hid that)."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

from systemtools import TOOLS

TESTS = Path(__file__).parent


# How a test module runs each tool: as the first word of a command, or through
# the helper that finds it.
USES = {"xvfb-run": r"""[(\[]\s*["']xvfb-run["']""", "nginx": r"""[(\[]\s*["']nginx["']|nginx_binary\(|Balancer\(""",
        "chromium-headless-shell": r"""system_tool\(["']chromium-headless-shell["']\)|chromium\.launch\(|\blaunch\(p\)""",
        "node": r"""system_tool\(["']node["']\)"""}


def _files_naming(tool: str) -> list[Path]:
    """Test modules that run ``tool``."""
    pattern = re.compile(USES[tool])
    return [p for p in sorted(TESTS.glob("test_*.py")) if p.name != Path(__file__).name
            and pattern.search(p.read_text())]


def test_every_test_naming_a_tool_is_marked():
    assert set(USES) == set(TOOLS), "say in USES how a test runs each tool of systemtools.TOOLS"
    for tool in TOOLS:
        for path in _files_naming(tool):
            text = path.read_text()
            assert f'requires_tool("{tool}")' in text, (
                f"{path.name} uses {tool} but has no @pytest.mark.requires_tool({tool!r}): on a machine "
                "without it, it would fail instead of skipping")


def test_without_the_tools_their_tests_skip_and_say_why():
    files = sorted({str(p) for tool in TOOLS for p in _files_naming(tool)})
    assert files, "no test uses an optional tool: this test has nothing left to check"
    env = {**os.environ, "CAVECLOD_TESTS_WITHOUT": "all"}
    r = subprocess.run([sys.executable, "-m", "pytest", "-q", "-rs", "-p", "no:cacheprovider", "-m", "requires_tool",
                        *files], capture_output=True, text=True, timeout=300, env=env, cwd=TESTS.parent)
    out = r.stdout + r.stderr
    assert r.returncode == 0, out[-3000:]
    assert re.search(r"\d+ skipped", out) and not re.search(r"\d+ (passed|failed|error)", out), out[-3000:]
    for tool in TOOLS:
        assert f"{tool} is not installed" in out, out[-3000:]
