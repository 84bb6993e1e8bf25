"""``caveclod serve --processes N``: N server processes on one port, and their supervisor.

One Python process makes every stream's I/O on one event-loop thread:
gRPC's own work per frame (about 0.26 ms here, measured with pre-serialized
replies) caps a process near 2,000 frames a second whatever the cores (the
README's service figures). Python's gRPC recommends processes for such
servers; this module runs N ``caveclod serve`` processes that bind the same
port with SO_REUSEPORT, so the kernel spreads connections over them, each
process mapping the same ``.cvc`` files (their pages are shared).

The supervisor (this process) starts them, prints the one ``listening on``
line once every one listens, forwards SIGTERM/SIGINT so that each drains,
restarts one that dies (at most RESTARTS a minute), and serves the sum of
their Prometheus metrics on ``--metrics-port``. The processes share no
state: a session lives in the process whose connection opened it, and a
resume that the kernel hands to another process gets a fresh session (the
client library continues it from a keyframe, as after a failover between
replicas). ``--max-sessions`` is per process.
"""

from __future__ import annotations

import ctypes
import http.server
import signal
import socket
import subprocess
import sys
import threading
import time
import urllib.request

from . import logs
from .app import STOP_GRACE_SECONDS

RESTARTS = 5                 # restarts of dead processes allowed within a minute, then the supervisor gives up
_PR_SET_PDEATHSIG = 1


def supervise(args) -> int:
    """Run ``args.processes`` servers of ``args`` on one port until a signal; the exit status."""
    logs.configure(args.log_format)
    reserved = None
    port = args.port
    if port == 0:                 # pick the port for all of them: hold it (SO_REUSEPORT) until they listen
        reserved = socket.socket(socket.AF_INET6 if ":" in args.host else socket.AF_INET, socket.SOCK_STREAM)
        reserved.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEPORT, 1)
        reserved.bind((args.host, 0))
        port = reserved.getsockname()[1]
    stop = threading.Event()
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, lambda signum, frame: stop.set())
    group = _Group(args, port)
    try:
        group.start_all()
    except RuntimeError as exc:
        group.kill()
        print(f"caveclod: error: {exc}", file=sys.stderr)
        return 1
    finally:
        if reserved is not None:
            reserved.close()
    print(f"listening on {args.host}:{port}", flush=True)
    if args.web_port is not None:
        print(f"viewer on http://{args.host if args.web_host is None else args.web_host}:{args.web_port}/", flush=True)
    exporter = None
    if args.metrics_port is not None:
        exporter = _serve_metrics(args.metrics_host, args.metrics_port, group)
        logs.event("server.metrics", port=exporter.server_port)
    logs.event("server.processes", processes=args.processes, port=port)
    status = group.watch(stop)
    if exporter is not None:
        exporter.shutdown()
    return status


class _Group:
    """The server processes: start, watch, restart, stop."""

    def __init__(self, args, port: int):
        self.args, self.port = args, port
        self.procs: list[subprocess.Popen | None] = [None] * args.processes
        self.metrics_ports: list[int | None] = [None] * args.processes
        self.restarts: list[float] = []

    def _command(self) -> list:
        a = self.args
        cmd = [sys.executable, "-m", "caveclod.cli", "serve", *a.meshes, "--host", a.host, "--port", str(self.port),
               "--reuse-port", "--log-format", a.log_format]
        for name in ("max_sessions", "max_cameras", "ack_window", "resume_ttl", "drain_seconds", "max_faces",
                     "max_ops", "token_file", "tls_cert", "tls_key", "web_port", "web_host", "transport",
                     "checked_dir"):
            value = getattr(a, name)
            if value is not None:
                cmd += ["--" + name.replace("_", "-"), str(value)]
        if a.metrics_port is not None:         # each its own exporter on loopback; we serve their sum
            cmd += ["--metrics-port", "0", "--metrics-host", "127.0.0.1", "--announce-metrics"]
        return cmd

    def start(self, i: int) -> None:
        proc = subprocess.Popen(self._command(), stdout=subprocess.PIPE, text=True, preexec_fn=_die_with_parent)
        line = proc.stdout.readline()
        if not line.startswith("listening on "):
            proc.kill()
            proc.wait()
            raise RuntimeError(f"server process {i} did not start (it printed {line.strip()!r}); its errors are above")
        if self.args.web_port is not None:
            proc.stdout.readline()                  # its "viewer on" line: the supervisor prints one
        if self.args.metrics_port is not None:
            self.metrics_ports[i] = int(proc.stdout.readline().split()[-1])
        threading.Thread(target=proc.stdout.read, daemon=True).start()       # keep the pipe drained
        self.procs[i] = proc
        logs.event("server.process_started", process=i, pid=proc.pid)

    def start_all(self) -> None:
        for i in range(len(self.procs)):
            self.start(i)

    def watch(self, stop: threading.Event) -> int:
        """Until ``stop``: restart processes that die; then drain them all. 0 when every one drained cleanly."""
        while not stop.wait(0.2):
            for i, proc in enumerate(self.procs):
                if proc is not None and proc.poll() is not None:
                    logs.event("server.process_exited", process=i, pid=proc.pid, status=proc.returncode)
                    now = time.monotonic()
                    self.restarts = [t for t in self.restarts if now - t < 60.0] + [now]
                    if len(self.restarts) > RESTARTS:
                        logs.event("server.giving_up", restarts=len(self.restarts))
                        self.stop()
                        return 1
                    try:
                        self.start(i)
                    except RuntimeError as exc:
                        logs.event("server.restart_failed", process=i, error=str(exc))
                        self.procs[i] = None
            if not any(self.procs):
                return 1
        logs.event("server.signal")
        return self.stop()

    def stop(self) -> int:
        """SIGTERM every process (each drains), wait for them; 0 when all exited 0."""
        live = [p for p in self.procs if p is not None and p.poll() is None]
        for p in live:
            p.send_signal(signal.SIGTERM)
        deadline = time.monotonic() + self.args.drain_seconds + STOP_GRACE_SECONDS + 10.0
        status = 0
        for p in live:
            try:
                status |= p.wait(max(deadline - time.monotonic(), 0.1)) != 0
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()
                status = 1
        logs.event("server.stopped")
        return status

    def kill(self) -> None:
        for p in self.procs:
            if p is not None and p.poll() is None:
                p.kill()
                p.wait()


def _die_with_parent() -> None:
    """In a server process: be killed if the supervisor dies (so no server outlives a SIGKILLed supervisor)."""
    try:
        ctypes.CDLL(None, use_errno=True).prctl(_PR_SET_PDEATHSIG, signal.SIGKILL)
    except (OSError, AttributeError):      # not Linux: the supervisor's own stop still ends them
        pass


# -- the summed metrics -----------------------------------------------------------------------

def sum_metrics(texts: list) -> str:
    """Prometheus text expositions of several processes, summed sample by sample (counters,
    gauges and histogram buckets of caveclod all add up; ``_created`` times take the earliest),
    as one exposition."""
    from prometheus_client import CollectorRegistry, generate_latest
    from prometheus_client.metrics_core import Metric
    from prometheus_client.parser import text_string_to_metric_families
    families: dict = {}
    for text in texts:
        for family in text_string_to_metric_families(text):
            _, _, samples = families.setdefault(family.name, (family.type, family.documentation, {}))
            for s in family.samples:
                key = (s.name, tuple(sorted(s.labels.items())))
                if key not in samples:
                    samples[key] = s.value
                elif s.name.endswith("_created"):
                    samples[key] = min(samples[key], s.value)
                else:
                    samples[key] += s.value

    class Summed:
        def collect(self):
            for name, (kind, doc, samples) in families.items():
                metric = Metric(name, doc, kind)
                for (sample, labels), value in samples.items():
                    metric.add_sample(sample, dict(labels), value)
                yield metric

    registry = CollectorRegistry(auto_describe=False)
    registry.register(Summed())
    return generate_latest(registry).decode()


def _serve_metrics(host: str, port: int, group: _Group) -> http.server.ThreadingHTTPServer:
    """/metrics: the sum of every live process's metrics, plus ``caveclod_processes``."""

    class Handler(http.server.BaseHTTPRequestHandler):
        def do_GET(self):
            if self.path.split("?")[0] != "/metrics":
                self.send_error(404, "only /metrics is served here")
                return
            texts, live = [], 0
            for proc, mport in zip(group.procs, group.metrics_ports):
                if proc is None or proc.poll() is not None or mport is None:
                    continue
                try:
                    texts.append(urllib.request.urlopen(f"http://127.0.0.1:{mport}/metrics", timeout=2).read().decode())
                    live += 1
                except OSError:
                    continue                   # a process restarting: left out of this scrape
            body = (sum_metrics(texts) + "# HELP caveclod_processes Server processes answering this scrape\n"
                    f"# TYPE caveclod_processes gauge\ncaveclod_processes {live}\n").encode()
            self.send_response(200)
            self.send_header("Content-Type", "text/plain; version=0.0.4; charset=utf-8")
            self.send_header("Content-Length", str(len(body)))
            self.end_headers()
            self.wfile.write(body)

        def log_message(self, *args):          # no access log on stderr
            pass

    server = http.server.ThreadingHTTPServer((host, port), Handler)
    threading.Thread(target=server.serve_forever, daemon=True, name="caveclod-metrics").start()
    return server
