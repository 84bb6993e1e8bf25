"""The browser front scaled out on loopback: two `caveclod serve --web-port`
replicas behind a real nginx configured from deploy/nginx/caveclod-web.conf.template.

A session's affinity key in its WebSocket address brings every resume to
the replica that holds the session; the page and its files come through the
balancer; the access log keeps tokens out; and a page whose replica is
killed carries on from the other one (a fresh session, the vertex buffer
kept). nginx and Chromium come from the system; where one is missing its
tests skip. Processes are stopped by pid in ``finally`` blocks.
"""

from __future__ import annotations

import asyncio
import os
import signal
import time

import aiohttp
import pytest

from caveclod import paths
from caveclod.client import SessionProtocol
from caveclod.server import web

from failover import Balancer, Replica, nginx_binary
from service import WAIT, stop_process
from webclient import OPTIONS, WsClient

pytestmark = pytest.mark.requires_tool("nginx")


@pytest.fixture
def front(terrain_path, tmp_path):
    """Two replicas with web ports and nginx in front of both: (replicas, balancer)."""
    replicas, balancer = [], None
    try:
        for name in ("a", "b"):
            replicas.append(Replica(terrain_path, tmp_path, name, "--web-port", "0", "--resume-ttl", "30"))
        balancer = Balancer(nginx_binary(), replicas, web=True)
        yield replicas, balancer
    finally:
        if balancer is not None:
            balancer.stop()
        for r in replicas:
            stop_process(r.proc)


async def _open_and_drop(url: str, protocol: SessionProtocol) -> None:
    """Open (or resume) a session, get one pose's frame, and drop the connection without a Close."""
    async with aiohttp.ClientSession() as http:
        async with http.ws_connect(url, protocols=[web.SUBPROTOCOL]) as ws:
            client = WsClient(ws, protocol)
            await client.send(protocol.open_message())
            while not protocol.ready:
                assert await client.receive() is not None or protocol.ready, client.status
            lo, hi = protocol.info.mesh.bounds_min, protocol.info.mesh.bounds_max
            pose = paths.circle((lo.x, lo.y, lo.z), (hi.x, hi.y, hi.z), 0, protocol.pose_seq)
            await client.send(protocol.pose_message(0, pose.eye, pose.target, pose.up))
            assert await client.receive() is not None


def test_resumes_reach_the_replica_that_holds_the_session(front):
    replicas, balancer = front
    held_by = []

    async def go():
        for i in range(12):
            key = f"{i:032x}"
            url = f"ws://127.0.0.1:{balancer.web_port}/v1/session?affinity={key}&token=secret-{i}"
            protocol = SessionProtocol("terrain", 1, OPTIONS)
            await _open_and_drop(url, protocol)
            assert not protocol.info.resumed
            await _open_and_drop(url, protocol)          # the same key: the same replica, which resumes
            assert protocol.info.resumed and protocol.divergences == 0, key
            held_by.append(next(r.name for r in replicas if r.holds(protocol.token)))
    asyncio.run(asyncio.wait_for(go(), WAIT))
    assert set(held_by) == {"a", "b"}, "12 keys hashed to one replica"
    time.sleep(0.2)                                       # nginx logs a request when it ends
    log = "\n".join(balancer.access_log())
    assert "/v1/session" in log and "secret-" not in log, "the access log holds a token"


@pytest.mark.requires_tool("chromium-headless-shell")
def test_a_page_through_the_balancer_outlives_its_replica(front):
    from playwright.sync_api import sync_playwright

    from test_web_chromium import Page, launch
    replicas, balancer = front
    with sync_playwright() as p:
        browser = launch(p)
        try:
            with Page(browser, f"http://127.0.0.1:{balancer.web_port}/?mesh=terrain&trajectory=flyover&cameras=2") \
                    as page:
                stats = page.wait(lambda s: s["frames"] >= 20)
                assert stats["frames"] >= 20 and stats["error"] is None, stats
                token = page.page.evaluate("window.caveclodSession.token")
                victim = next(r for r in replicas if r.holds(token))
                os.kill(victim.proc.pid, signal.SIGKILL)
                frames = stats["frames"]
                stats = page.wait(lambda s: s["frames"] >= frames + 30 and s["resumes"] >= 1 or s["error"])
                # The page resumed through the balancer, which took it to the other
                # replica: a fresh session there, its vertex buffer offered by hash.
                assert stats["error"] is None and stats["resumes"] >= 1 and stats["divergences"] == 0, stats
                new_token = page.page.evaluate("window.caveclodSession.token")
                assert new_token != token and any(r.holds(new_token) for r in replicas if r is not victim)
                assert page.page.evaluate("window.caveclodSession.info.vertexBufferCached")
                # The killed connection's errors are the browser's own log lines; no script error.
                assert not [e for e in page.console_errors if "WebSocket" not in e], page.console_errors
        finally:
            browser.close()
