"""Helpers of the multi-replica tests: the shipped nginx template rendered
for loopback, nginx and `caveclod serve` replicas started and stopped by pid,
and viewers flying through the balancer while a replica goes away.

Everything listens on 127.0.0.1 (ports found by binding port 0); every
process started here is stopped by its pid in a ``finally``; every loop is
bounded in count and time.
"""

from __future__ import annotations

import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

from service import ROOT, log_events, readline_within, stop_process, wait_until
from systemtools import system_tool

TEMPLATE = Path(ROOT) / "deploy" / "nginx" / "caveclod.conf.template"
PLACEHOLDERS = ("CAVECLOD_LISTEN", "CAVECLOD_RESOLVER", "CAVECLOD_UPSTREAM_SERVERS")
WEB_TEMPLATE = Path(ROOT) / "deploy" / "nginx" / "caveclod-web.conf.template"
WEB_PLACEHOLDERS = ("CAVECLOD_WEB_LISTEN", "CAVECLOD_WEB_UPSTREAM_SERVERS")
RATE = 30.0                      # poses a second, each viewer


def render_template(template: Path = TEMPLATE, placeholders=PLACEHOLDERS, **values: str) -> str:
    """An nginx template with every ${NAME} replaced, as the nginx image's envsubst does
    (nginx's own $variables are left alone); KeyError when a placeholder has no value."""
    missing = set(placeholders) - set(values)
    if missing:
        raise KeyError(f"no value for {sorted(missing)}")
    return re.sub(r"\$\{(\w+)\}", lambda m: values[m.group(1)], template.read_text())


def nginx_binary() -> str | None:
    return system_tool("nginx")


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Replica:
    """A `caveclod serve` process on 127.0.0.1:0 whose JSON log goes to a file."""

    def __init__(self, mesh: Path, workdir: Path, name: str, *args: str):
        self.name, self.log = name, workdir / f"{name}.log"
        cmd = [sys.executable, "-m", "caveclod.cli", "serve", str(mesh), "--host", "127.0.0.1", "--port", "0",
               "--log-format", "json", *args]
        with open(self.log, "w") as err:
            self.proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=err, text=True, cwd=ROOT)
        try:
            line = readline_within(self.proc.stdout, 60.0)
            if not line.startswith("listening on "):
                raise AssertionError(f"{name} printed {line!r} first; log: {self.log.read_text()[-2000:]}")
            self.port = int(line.rsplit(":", 1)[1])
            self.web_port = None
            if "--web-port" in args:      # printed right after (often read into the pipe's buffer already)
                line = self.proc.stdout.readline()
                if not line.startswith("viewer on "):
                    raise AssertionError(f"{name} printed {line!r} second; log: {self.log.read_text()[-2000:]}")
                self.web_port = int(line.strip().rstrip("/").rsplit(":", 1)[1])
            assert wait_until(lambda: "server.ready" in self.log.read_text(), timeout=60), "kernels did not load"
        except BaseException:
            stop_process(self.proc)
            raise

    def events(self, name: str) -> list[dict]:
        return log_events(self.log.read_text().splitlines(), name)

    def holds(self, token: str) -> bool:
        """Whether this replica opened the session of ``token``."""
        return any(e["session"] == token[:8] for e in self.events("session.opened"))


class Balancer:
    """nginx, configured from deploy/nginx/caveclod.conf.template, in front of ``replicas``;
    with ``web``, also from caveclod-web.conf.template in front of their web ports (``web_port``)."""

    def __init__(self, nginx: str, replicas: list[Replica], web: bool = False):
        self.dir = Path(tempfile.mkdtemp(prefix="caveclod-nginx-"))
        os.chmod(self.dir, 0o755)                 # workers (nobody, when we are root) read temp paths here
        self.port = free_port()
        servers = " ".join(f"server 127.0.0.1:{r.port} max_fails=0;" for r in replicas)
        (self.dir / "caveclod.conf").write_text(render_template(
            CAVECLOD_LISTEN=f"127.0.0.1:{self.port}", CAVECLOD_RESOLVER="", CAVECLOD_UPSTREAM_SERVERS=servers))
        includes = f" include {self.dir}/caveclod.conf;\n"
        self.web_port = None
        if web:
            self.web_port = free_port()
            web_servers = " ".join(f"server 127.0.0.1:{r.web_port} max_fails=0;" for r in replicas)
            (self.dir / "caveclod-web.conf").write_text(render_template(
                WEB_TEMPLATE, WEB_PLACEHOLDERS, CAVECLOD_WEB_LISTEN=f"127.0.0.1:{self.web_port}",
                CAVECLOD_WEB_UPSTREAM_SERVERS=web_servers))
            includes += f" include {self.dir}/caveclod-web.conf;\n"
        d = self.dir
        # The main file of the nginx image, cut down: the template goes inside http { }.
        (d / "nginx.conf").write_text(
            f"worker_processes 1;\npid {d}/nginx.pid;\nerror_log {d}/error.log info;\n"
            "events { worker_connections 1024; }\n"
            f"http {{\n client_body_temp_path {d}/client_body;\n proxy_temp_path {d}/proxy;\n"
            f" fastcgi_temp_path {d}/fastcgi;\n uwsgi_temp_path {d}/uwsgi;\n scgi_temp_path {d}/scgi;\n"
            f"{includes}}}\n")
        cmd = [nginx, "-p", str(d), "-c", str(d / "nginx.conf"), "-g", "daemon off;"]
        test = subprocess.run([*cmd[:-2], "-t"], capture_output=True, text=True, timeout=30)
        if test.returncode != 0:
            shutil.rmtree(d, ignore_errors=True)
            raise AssertionError(f"nginx -t refuses the rendered template: {test.stderr}")
        with open(d / "access.log", "w") as out:      # access_log /dev/stdout in the template
            self.proc = subprocess.Popen(cmd, stdout=out, stderr=subprocess.STDOUT)
        try:
            assert wait_until(self._accepts, timeout=10), f"nginx does not listen: {self.error_log()}"
        except BaseException:
            self.stop()
            raise

    def _accepts(self) -> bool:
        try:
            socket.create_connection(("127.0.0.1", self.port), timeout=0.5).close()
            return True
        except OSError:
            return self.proc.poll() is not None      # exited: stop waiting (the assertion says why)

    def access_log(self) -> list[str]:
        return (self.dir / "access.log").read_text().splitlines()

    def error_log(self) -> str:
        path = self.dir / "error.log"
        return path.read_text()[-3000:] if path.exists() else ""

    def stop(self) -> None:
        """SIGTERM (nginx's fast shutdown) to the master, SIGKILL after a bounded wait; then its workers,
        by pid, should any have outlived a killed master."""
        workers = _children(self.proc.pid)
        stop_process(self.proc, signal.SIGTERM)
        for pid in workers:
            if wait_until(lambda: not _alive(pid), timeout=5):
                continue
            try:
                os.kill(pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
        shutil.rmtree(self.dir, ignore_errors=True)


def _children(pid: int) -> list[int]:
    try:
        return [int(x) for x in Path(f"/proc/{pid}/task/{pid}/children").read_text().split()]
    except OSError:
        return []


def _alive(pid: int) -> bool:
    try:
        return "nginx" in Path(f"/proc/{pid}/cmdline").read_text() and \
            Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


@dataclass
class Viewer:
    """One client session through the balancer and what it saw: (time, frame_seq, token, keyframe) per frame."""

    index: int
    client: object
    session: object
    frames: list = field(default_factory=list)
    error: BaseException | None = None

    def fly(self, until: float, lo, hi) -> None:
        """Poses at RATE Hz until ``until`` (monotonic), frames read between them; exceptions kept."""
        from caveclod.paths import flyover
        s, period, tick = self.session, 1.0 / RATE, time.monotonic()
        try:
            for _ in range(int((until - tick) * RATE) + 2):         # bounded: a tick lasts a period or more
                now = time.monotonic()
                if now >= until:
                    break
                s.send_pose(0, *flyover(lo, hi, self.index, now, seconds_per_lap=8.0))
                tick = max(tick + period, now)                      # ticks missed (a failover) are skipped
                for _ in range(100):                                # frames until the next tick
                    f = s.next_frame(timeout=max(tick - time.monotonic(), 0.001))
                    if f is None:
                        break
                    self.frames.append((time.monotonic(), f.frame_seq, s.protocol.token,
                                        any(c.keyframe for c in f.cameras.values())))
        except BaseException as exc:          # reported by the test, with the viewer's index
            self.error = exc

    def gap(self, since: float) -> tuple[float, int]:
        """The longest wait for a frame after ``since``: (milliseconds, frames missed at RATE Hz)."""
        times = [t for t, *_ in self.frames]
        before = [t for t in times if t < since]
        after = [t for t in times if t >= since]
        points = before[-1:] + after
        longest = max((b - a for a, b in zip(points, points[1:])), default=float("inf"))
        return 1e3 * longest, max(0, round(longest * RATE) - 1)


def open_viewers(viewers: list, target: str, replicas: list[Replica], cache_dir: Path, per_replica: int = 2,
                 limit: int = 64) -> list[Viewer]:
    """Open sessions through the balancer into ``viewers`` until every replica holds ``per_replica``
    (at most ``limit`` tries). A new session's key is random, so which replica it lands on is too;
    nginx's ring over two loopback names can split keys 90/10, so a session that lands on a replica
    already holding ``per_replica`` is closed again (freeing its --max-sessions slot) and another tried."""
    from caveclod.client import Client
    counts = [0] * len(replicas)
    for _ in range(limit):
        client = Client(target, cache_dir=cache_dir)
        session = client.session("terrain", width=640, height=360)
        token = session.protocol.token
        assert wait_until(lambda: any(r.holds(token) for r in replicas), timeout=5), "no replica logged the session"
        home = next(i for i, r in enumerate(replicas) if r.holds(token))
        if counts[home] >= per_replica:
            close_viewers([Viewer(-1, client, session)])
            continue
        counts[home] += 1
        viewers.append(Viewer(len(viewers), client, session))
        if min(counts) >= per_replica:
            return viewers
    raise AssertionError(f"{limit} sessions did not reach {per_replica} on every replica: {counts}")


def close_viewers(viewers: list[Viewer]) -> None:
    for v in viewers:
        try:
            v.session.close(timeout=2.0)
        except Exception:                       # the test has its figures; closing is best effort
            pass
        v.client.close()
