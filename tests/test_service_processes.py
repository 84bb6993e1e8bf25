"""`caveclod serve --processes N`: one port, N processes, one supervisor that drains,
restarts and sums their metrics."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import urllib.request

import pytest

from caveclod import cli
from caveclod.server.processes import sum_metrics

from service import ROOT, log_events, readline_within, stop_process, wait_until


class Supervisor:
    """`caveclod serve --processes 2` on 127.0.0.1:0 with summed metrics; its stderr collected."""

    def __init__(self, terrain_path, *extra):
        import threading
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "caveclod.cli", "serve", str(terrain_path), "--host", "127.0.0.1", "--port", "0",
             "--processes", "2", "--metrics-port", "0", "--metrics-host", "127.0.0.1", "--log-format", "json",
             "--drain-seconds", "2", *extra],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT)
        self.lines: list = []
        threading.Thread(target=lambda: [self.lines.append(x) for x in self.proc.stderr], daemon=True).start()
        line = readline_within(self.proc.stdout, 120.0)
        if not line.startswith("listening on "):
            stop_process(self.proc)
            raise AssertionError(f"the supervisor printed {line!r}; stderr: {''.join(self.lines)[-2000:]}")
        self.port = int(line.rsplit(":", 1)[1])
        assert wait_until(lambda: log_events(self.lines, "server.metrics") and log_events(self.lines, "server.processes"))
        self.metrics_port = log_events(self.lines, "server.metrics")[-1]["port"]

    def children(self) -> list:
        return [e["pid"] for e in log_events(self.lines, "server.process_started")]

    def metrics(self) -> dict:
        text = urllib.request.urlopen(f"http://127.0.0.1:{self.metrics_port}/metrics", timeout=10).read().decode()
        out = {}
        for line in text.splitlines():
            if line and not line.startswith("#"):
                name, value = line.rsplit(" ", 1)
                out[name] = float(value)
        return out


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    try:               # a zombie (exited, not yet reaped by its parent) is not serving
        return open(f"/proc/{pid}/stat").read().split()[2] != "Z"
    except OSError:
        return False


@pytest.mark.parametrize("transport", ["grpc", "h2"])
def test_processes_share_the_port_drain_together_and_sum_their_metrics(terrain_path, tmp_path, capsys, transport):
    sup = Supervisor(terrain_path, "--transport", transport)
    children = sup.children()
    try:
        assert len(children) == 2 and all(_alive(p) for p in children)
        # Both listening (a child still starting takes no connection: on a loaded machine the
        # other one got all eight).
        assert wait_until(lambda: len(log_events(sup.lines, "server.ready")) >= 2)
        # Eight connections, spread by the kernel: both processes hold sessions. The kernel hashes
        # each connection to a listener, so all eight land on one process in 1 run of 128 (seen
        # once, in a fresh checkout's test run): a run whose sessions all went to one process is
        # followed by another, at most three in all.
        frames = 0
        for runs in range(1, 4):
            status = cli.main(["loadtest", "--target", f"127.0.0.1:{sup.port}", "--sessions", "8", "--duration",
                               "2", "--rate", "20", "--json", "--cache-dir", str(tmp_path)])
            report = json.loads(capsys.readouterr().out)
            assert status == 0 and report["divergences"] == 0 and report["errors"] == {}
            frames += report["frames"]
            holders = {e["pid"] for e in log_events(sup.lines, "session.opened")}
            if holders == set(children):
                break
        assert holders == set(children), holders
        m = sup.metrics()
        assert m["caveclod_processes"] == 2
        assert m["caveclod_frames_total"] >= frames
        assert m['caveclod_session_ends_total{reason="closed"}'] == 8 * runs
    finally:
        status = stop_process(sup.proc, signal.SIGTERM)
    assert status == 0
    assert wait_until(lambda: not any(_alive(p) for p in children), 10.0)
    assert log_events(sup.lines, "server.stopped")


def test_a_dead_process_is_restarted_and_a_killed_supervisor_takes_its_processes_along(terrain_path):
    sup = Supervisor(terrain_path)
    try:
        first, second = sup.children()
        os.kill(first, signal.SIGKILL)
        assert wait_until(lambda: len(sup.children()) == 3, 60.0), "the dead process was not restarted"
        assert log_events(sup.lines, "server.process_exited")[0]["pid"] == first
        assert wait_until(lambda: sup.metrics()["caveclod_processes"] == 2, 30.0)
        children = sup.children()[1:]
    finally:
        stop_process(sup.proc, signal.SIGKILL)
    # No server outlives its supervisor (they die with it), so a restart finds the port free.
    assert wait_until(lambda: not any(_alive(p) for p in children), 10.0)


def test_summed_metrics_add_counters_gauges_and_buckets():
    a = ('# HELP x_total X\n# TYPE x_total counter\nx_total 2.0\n'
         '# HELP g G\n# TYPE g gauge\ng{mesh="t"} 1.0\n'
         '# HELP h H\n# TYPE h histogram\nh_bucket{le="0.1"} 1.0\nh_bucket{le="+Inf"} 3.0\nh_count 3.0\nh_sum 0.5\n')
    b = a.replace("x_total 2.0", "x_total 5.0").replace('g{mesh="t"} 1.0', 'g{mesh="t"} 4.0')
    text = sum_metrics([a, b])
    assert "x_total 7.0" in text and 'g{mesh="t"} 5.0' in text
    assert 'h_bucket{le="+Inf"} 6.0' in text and "h_sum 1.0" in text and "# TYPE h histogram" in text


def test_processes_must_be_positive(terrain_path, capsys):
    assert cli.main(["serve", str(terrain_path), "--processes", "0"]) == 2
    assert "--processes must be from 1 to 256" in capsys.readouterr().err


def test_processes_share_the_web_port(terrain_path):
    """--web-port with --processes: every process serves the viewer and WebSocket sessions on the one port."""
    import socket
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        web_port = s.getsockname()[1]
    sup = Supervisor(terrain_path, "--web-port", str(web_port))
    try:
        # Printed right after the listening line (already in the pipe's buffer: a plain readline).
        assert sup.proc.stdout.readline().strip() == f"viewer on http://127.0.0.1:{web_port}/"
        assert wait_until(lambda: len(log_events(sup.lines, "server.ready")) == 2, 60.0)
        for _ in range(4):                   # connections spread over the processes; each answers
            page = urllib.request.urlopen(f"http://127.0.0.1:{web_port}/", timeout=10).read().decode()
            assert "viewer.js" in page
        started = [e["web_port"] for e in log_events(sup.lines, "server.started")]
        assert started == [web_port, web_port]
    finally:
        stop_process(sup.proc)


def test_processes_need_a_web_port_number(terrain_path, capsys):
    assert cli.main(["serve", str(terrain_path), "--processes", "2", "--web-port", "0"]) == 2
    assert "give a port number, not 0" in capsys.readouterr().err
    assert cli.main(["serve", str(terrain_path), "--web-port", "70000"]) == 2
    assert "--web-port must be a port number" in capsys.readouterr().err
