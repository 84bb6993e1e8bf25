"""The LOD service under load: sessions x 30 Hz, parallel refinement, start-up.

    python benchmarks/service.py [--size 708] [--sessions 8,16,32,48] [--duration 20]

On the 1M-triangle default terrain (``caveclod build default --size 708``),
a ``caveclod serve`` process and a ``caveclod loadtest`` process share this
machine: N sessions of one camera each, 30 poses a second along the flyover,
1280x720, 60 degrees, 1 px. For each N: pose -> frame latency p50/p99 (timed
by pose_seq at the client), frames/s, bytes per frame and per changed
triangle, divergences and errors, and the CPU each process used (from
/proc: they share the machine's cores), with the part of the server's that
refinement took (``caveclod_refine_cpu_seconds_total``, per-thread CPU
time of the updates).

Then:

* **parallel refinement**: 2 sessions whose cameras jump between far
  poses, each answered at once by a large update, for ``--parallel-seconds``;
  the rate of
  ``caveclod_refine_cpu_seconds_total`` is the cores refinement used (the
  kernels release the GIL);
* **start-up**: with a 2M-triangle mesh (``--size 1024``), the seconds from
  starting ``caveclod serve`` to health SERVING, and to the first frame of a
  session, once numba's cache is warm (median of 5).

Writes ``benchmarks/results/service.json`` (sections skipped with ``--skip``
keep their earlier figures) and ``service_latency.png`` (``--out`` elsewhere).
Each load level also records the server's memory: private, mapped-mesh and
all mapped files' resident bytes, idle and at peak, and the camera states'
bytes; the
``shared`` section runs two servers on one mesh to show the mapped mesh
shared between processes (proportional against mapped resident bytes).
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import statistics
import subprocess
import sys
import threading
import time
import urllib.request
from pathlib import Path

import numpy as np

RESULTS = Path(__file__).parent / "results"
TICK = os.sysconf("SC_CLK_TCK")


def mesh_path(size: int) -> Path:
    """benchmarks/results/default_SIZE.cvc, built when absent."""
    path = RESULTS / f"default_{size}.cvc"
    from caveclod.builder.version import made_by_this_code
    if not made_by_this_code(path):           # absent, or built by other code: build it again
        import caveclod
        RESULTS.mkdir(parents=True, exist_ok=True)
        print(f"building the default terrain --size {size} ...", file=sys.stderr)
        caveclod.build("default", size=size).save(path)
    return path


def cpu_seconds(pid: int) -> float:
    """User + system CPU seconds so far of a process (all its threads) and its children (a
    ``--processes`` supervisor's servers)."""
    total = 0.0
    for p in process_tree(pid):
        try:
            fields = Path(f"/proc/{p}/stat").read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        total += (int(fields[11]) + int(fields[12])) / TICK
    return total


def process_tree(pid: int) -> list:
    """``pid`` and its descendants' pids."""
    out, todo = [], [pid]
    while todo:
        p = todo.pop()
        out.append(p)
        try:
            for task in Path(f"/proc/{p}/task").iterdir():
                todo += [int(c) for c in (task / "children").read_text().split()]
        except OSError:
            continue
    return out


def machine_busy() -> float:
    """CPU seconds the whole machine has been busy (every process, ours or not, and steal)."""
    user, nice, system, idle, iowait, irq, softirq, steal = (int(x) for x in open("/proc/stat").readline().split()[1:9])
    return (user + nice + system + irq + softirq + steal) / TICK


def metrics(port: int) -> dict:
    text = urllib.request.urlopen(f"http://127.0.0.1:{port}/metrics", timeout=10).read().decode()
    return {line.split(" ")[0]: float(line.split(" ")[1]) for line in text.splitlines()
            if line and not line.startswith("#")}


class Server:
    """A ``caveclod serve`` (or another server command) on 127.0.0.1:0 with metrics, stopped by pid."""

    def __init__(self, mesh: Path, *extra: str, command: list | None = None):
        cmd = command or [sys.executable, "-m", "caveclod.cli", "serve"]
        self.proc = subprocess.Popen([*cmd, str(mesh), "--host", "127.0.0.1", "--port", "0", "--metrics-port", "0",
                                      "--metrics-host", "127.0.0.1", "--log-format", "json", *extra],
                                     stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        line = self.proc.stdout.readline()
        if not line.startswith("listening on "):
            self.stop()
            raise RuntimeError(f"server did not start: {line!r} {self.proc.stderr.read()[-2000:]}")
        self.port = int(line.rsplit(":", 1)[1])
        # Under --processes N: N processes get ready, then the supervisor
        # logs its (summed) metrics port just before server.processes.
        processes = int(extra[extra.index("--processes") + 1]) if "--processes" in extra else 1
        ready = 0
        while ready < processes or (processes > 1 and not getattr(self, "supervised", False)):
            event = json.loads(self.proc.stderr.readline())
            if event["event"] == "server.metrics":
                self.metrics_port = event["port"]
            elif event["event"] == "server.ready":
                ready += 1
            elif event["event"] == "server.processes":
                self.supervised = True
        threading.Thread(target=self.proc.stderr.read, daemon=True).start()    # keep the pipe drained

    def stop(self) -> None:
        if self.proc.poll() is None:
            os.kill(self.proc.pid, signal.SIGKILL)
        self.proc.wait(30)


def loadtest(port: int, sessions: int, duration: float, plot: Path | None = None, rate: float = 30.0,
             processes: int = 1, encoding: str = "linked", connections: int = 4, transport: str = "auto",
             decoder: str = "auto") -> dict:
    """Run ``caveclod loadtest`` (in ``processes`` processes, over ``connections`` connections, with
    ``transport``: h2, grpc or auto, and the op-stream ``decoder``); its JSON report."""
    cmd = [sys.executable, "-m", "caveclod.cli", "loadtest", "--target", f"127.0.0.1:{port}", "--sessions",
           str(sessions), "--cameras", "1", "--duration", str(duration), "--rate", str(rate), "--trajectory",
           "flyover", "--tolerance", "1", "--width", "1280", "--height", "720", "--fov", "60", "--json", "--samples",
           "--cache-dir", str(RESULTS / "vertex-cache"), "--processes", str(processes), "--frame-encoding", encoding,
           "--connections", str(connections), "--transport", transport, "--decoder", decoder]
    if plot is not None:
        cmd += ["--plot", str(plot)]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    out, _ = proc.communicate(timeout=duration + 120)
    return json.loads(out)


def memory(pid: int) -> dict:
    """Resident bytes of a process: private (RssAnon); of the mapped .cvc files (MeshRss: the mesh pages
    it touched, shared through the page cache with every process that maps the same file) and its
    proportional share of them (MeshPss: each page divided among the processes mapping it); and of
    every mapped file, shared libraries included (RssFile)."""
    out = {"MeshRss": 0, "MeshPss": 0}
    for p in process_tree(pid):                # a --processes supervisor: summed over its servers
        for line in Path(f"/proc/{p}/status").read_text().splitlines():
            if line.startswith(("RssAnon:", "RssFile:")):
                key = line.split(":")[0]
                out[key] = out.get(key, 0) + int(line.split()[1]) * 1024
        mesh = False
        for line in Path(f"/proc/{p}/smaps").read_text().splitlines():
            head = line.split()
            if head and "-" in head[0] and not head[0].endswith(":"):       # a mapping's first line
                mesh = head[-1].endswith(".cvc")
            elif mesh and head[0] in ("Rss:", "Pss:"):
                out["MeshRss" if head[0] == "Rss:" else "MeshPss"] += int(head[1]) * 1024
    return out


class SteadyWindow:
    """The server's CPU per frame in steady state: CPU and the server's own frame and refinement
    counters read at ``start`` (time.perf_counter: after the load test's start-up and first
    second of refining up from the base mesh) and ``seconds`` later, in a thread."""

    def __init__(self, server: "Server", start: float, seconds: float):
        self.server, self.start, self.seconds = server, start, max(seconds, 1.0)
        self.samples: list = []
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _sample(self) -> tuple:
        m = metrics(self.server.metrics_port)
        return (cpu_seconds(self.server.proc.pid), m["caveclod_frames_total"],
                m["caveclod_refine_cpu_seconds_total"])

    def _run(self) -> None:
        for at in (self.start, self.start + self.seconds):
            time.sleep(max(at - time.perf_counter(), 0.0))
            try:
                self.samples.append(self._sample())
            except (OSError, KeyError, ValueError):
                return

    def result(self) -> dict:
        self._thread.join(self.seconds + 30)
        if len(self.samples) < 2 or self.samples[1][1] <= self.samples[0][1]:
            return {}
        (c0, f0, r0), (c1, f1, r1) = self.samples
        frames = f1 - f0
        return {"steady_server_refine_ms_per_frame": round(1e3 * (r1 - r0) / frames, 3),
                "steady_server_other_ms_per_frame": round(1e3 * (c1 - c0 - (r1 - r0)) / frames, 3),
                "steady_frames_per_second": round(frames / self.seconds, 1)}


class Sampler:
    """Polls a server's memory and session gauges every ``period`` s in a thread; keeps the peaks."""

    def __init__(self, server: "Server", period: float = 0.5):
        self.server, self.period, self.peak = server, period, {}
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.wait(self.period):
            try:
                m = metrics(self.server.metrics_port)
                sample = {**memory(self.server.proc.pid), "sessions_active": m["caveclod_sessions_active"],
                          "camera_state_bytes": m["caveclod_camera_state_bytes"]}
            except (OSError, KeyError, ValueError):
                continue
            for k, v in sample.items():
                self.peak[k] = max(self.peak.get(k, 0), v)

    def stop(self) -> dict:
        self._stop.set()
        self._thread.join(5)
        return self.peak


def capacity(mesh: Path, sessions: int, duration: float, command: list | None = None, processes: int = 1,
             encoding: str = "linked", connections: int = 4, server_processes: int = 1, transport: str = "auto",
             server_transport: str = "grpc", decoder: str = "auto") -> dict:
    """One load level: server (``caveclod serve``, or ``command``) and load generator, with both processes'
    CPU, and the server's memory: idle (mesh mapped, kernels loaded) and the peak under load. The
    server's CPU is its process tree's (a ``--processes`` supervisor and its servers)."""
    extra = ["--processes", str(server_processes)] if server_processes > 1 else []
    if server_transport != "grpc":                    # an older checkout (--baseline) knows only grpc
        extra += ["--transport", server_transport]
    server = Server(mesh, "--max-sessions", str(max(64, sessions)), *extra, command=command)
    try:
        idle = memory(server.proc.pid)
        m0, cpu0, busy0, t0 = metrics(server.metrics_port), cpu_seconds(server.proc.pid), machine_busy(), \
            time.perf_counter()
        sampler = Sampler(server)
        window = SteadyWindow(server, start=t0 + 3.0 + 0.02 * sessions + 1.0, seconds=duration - 3.0)
        report = loadtest(server.port, sessions, duration, processes=processes, encoding=encoding,
                          connections=connections, transport=transport, decoder=decoder)
        peak = sampler.stop()
        report.update(window.result())
        m1, cpu1, busy1, t1 = metrics(server.metrics_port), cpu_seconds(server.proc.pid), machine_busy(), \
            time.perf_counter()
    finally:
        server.stop()
    MiB = 1 << 20
    report["server_memory_mib"] = {
        "idle_private": round(idle.get("RssAnon", 0) / MiB, 1), "idle_mesh": round(idle["MeshRss"] / MiB, 1),
        "idle_files": round(idle.get("RssFile", 0) / MiB, 1),
        "peak_private": round(peak.get("RssAnon", 0) / MiB, 1), "peak_mesh": round(peak.get("MeshRss", 0) / MiB, 1),
        "peak_files": round(peak.get("RssFile", 0) / MiB, 1),
        "peak_camera_states": round(peak.get("camera_state_bytes", 0) / MiB, 1)}
    report["peak_sessions_active"] = int(peak.get("sessions_active", 0))
    wall = t1 - t0
    report["server_cpu_cores"] = round((cpu1 - cpu0) / wall, 2)
    report["server_cpu_ms_per_frame"] = round(1e3 * (cpu1 - cpu0) / max(report["frames"], 1), 2)
    # Whatever else ran on the machine meanwhile (the loadtest's own start-up included): the noise.
    report["other_cpu_cores"] = round((busy1 - busy0) / wall - report["server_cpu_cores"]
                                      - report["client_cpu_cores"], 2)
    refine = m1["caveclod_refine_cpu_seconds_total"] - m0["caveclod_refine_cpu_seconds_total"]
    report["server_refine_cpu_cores"] = round(refine / wall, 2)
    frames = max(report["frames"], 1)
    report["server_refine_ms_per_frame"] = round(1e3 * refine / frames, 3)
    report["server_other_ms_per_frame"] = round(1e3 * (cpu1 - cpu0 - refine) / frames, 3)
    report["wall_s"] = round(wall, 1)
    return report


# The client's second pose when none waits at the server, this long after the
# first: sent together, the server would take the later one and skip the other.
REFILL_SECONDS = 0.001


def parallel_refinement(mesh: Path, seconds: float, pose_hz: float | None = 500.0, tolerance_px: float = 0.5,
                        server_transport: str = "grpc", size: tuple = (1280, 720), client: str = "h2") -> dict:
    """2 sessions whose camera jumps between far poses: the cores their refinement used.

    Each session's client keeps a new pose always pending, going round
    three far points of its camera's circle, so that the server always has
    a pose to refine for and each update is a large one. With ``pose_hz``
    it sends one every 1 / pose_hz seconds (faster than an update takes)
    without waiting for frames; the latest pose wins. With
    ``pose_hz=None`` it keeps two poses ahead of the one each frame answers
    (acking the frame on the first): one pose is always waiting, and the
    server parses few poses it will not use. (Until 2026-11-28 it sent one
    pose a frame after two: once the server had taken the later of two
    waiting poses, one pose was in flight at a time and the workers idled
    44 % of the time; refinement used 1.38 cores at 4-5 ms updates for it,
    1.50 once two stayed ahead.) The clients parse each frame only to
    ack it (an applying client would compete for this machine's two cores
    with the refinement it measures); the server still encodes every frame
    in full. The rate of ``caveclod_refine_cpu_seconds_total`` (per-thread
    CPU time of the updates) is the cores refinement used.

    ``client``: ``h2``, both sessions on one asyncio loop over
    :mod:`caveclod.client.h2wire` (the load generator's HTTP/2; either
    server transport takes it), or ``grpc``, a thread and a blocking gRPC
    stream each (what these runs used until 2026-11-28: 0.15-0.19 cores
    at 4-5 ms updates against the h2 client's 0.08-0.09, taken from the
    two cores the refinement shares).
    """
    import queue

    import grpc

    from caveclod.paths import flyover
    from caveclod.v1 import caveclod_pb2 as pb
    server = Server(mesh, "--transport", server_transport)
    stop = threading.Event()
    frames = [0, 0]
    lo, hi = mesh_bounds(mesh)

    def vec(v) -> pb.Vec3:
        return pb.Vec3(x=v[0], y=v[1], z=v[2])

    def open_message() -> pb.ClientMessage:
        return pb.ClientMessage(open=pb.Open(
            mesh=mesh.stem, cameras=1, vertex_buffer_hash="", client="benchmark",
            options=pb.RefineOptions(viewport_width=size[0], viewport_height=size[1], tolerance_px=tolerance_px)))

    def pose_message(k: int, seq: int, ack: int = 0) -> pb.ClientMessage:
        # Three far points of the camera's circle in turn: any two poses fewer
        # than three apart are far apart, so whichever waiting pose the server
        # takes, its update is a large one.
        eye, target, up = flyover(lo, hi, k, 20.0 * (seq % 3) + 0.001 * seq)
        return pb.ClientMessage(pose=pb.CameraPose(camera=0, pose_seq=seq, eye=vec(eye), target=vec(target),
                                                   up=vec(up), ack_frame_seq=ack))

    def fly_h2() -> None:
        """Both sessions on one event loop, over caveclod's HTTP/2 client."""
        import asyncio

        from caveclod.client.h2wire import H2Connection

        async def session(k: int) -> None:
            conn = await H2Connection.connect("127.0.0.1", server.port)
            loop = asyncio.get_running_loop()
            ended = loop.create_future()
            seq = 0

            def send_pose(ack: int = 0) -> None:
                nonlocal seq
                seq += 1
                call.send(pose_message(k, seq, ack).SerializeToString())

            def on_message(data: bytes) -> None:
                msg = pb.ServerMessage.FromString(data)
                if msg.WhichOneof("kind") == "frame" and not msg.frame.continued:
                    frames[k] += 1
                    if pose_hz is None:          # the pose after the one the server refines now
                        send_pose(msg.frame.frame_seq)
                        if seq < msg.frame.pose_seq + 2:     # it refines none: one for now, one for after
                            loop.call_later(REFILL_SECONDS, refill)
                    else:
                        call.send(pb.ClientMessage(ack=pb.Ack(frame_seq=msg.frame.frame_seq)).SerializeToString())
                    conn.flush()

            def refill() -> None:
                send_pose()
                conn.flush()

            def on_end(code, details) -> None:
                if not ended.done():
                    ended.set_result((code, details))
            call = conn.start_call("/caveclod.v1.Lod/Session", [], on_message, on_end)
            call.send(open_message().SerializeToString())
            send_pose()
            conn.flush()
            if pose_hz is None:
                loop.call_later(REFILL_SECONDS, refill)
            try:
                while not stop.is_set() and not ended.done():
                    await asyncio.sleep(0.1 if pose_hz is None else 1.0 / pose_hz)
                    if pose_hz is not None:
                        send_pose()
                        conn.flush()
            finally:
                call.cancel()
                conn.close()

        async def both() -> None:
            await asyncio.gather(session(0), session(1))
        asyncio.run(both())

    def session(k: int) -> None:
        requests: queue.Queue = queue.Queue()
        requests.put(open_message())
        with grpc.insecure_channel(f"127.0.0.1:{server.port}", [("grpc.max_receive_message_length", 8 << 20)]) as ch:
            call = ch.stream_stream("/caveclod.v1.Lod/Session", request_serializer=pb.ClientMessage.SerializeToString,
                                    response_deserializer=pb.ServerMessage.FromString)(iter(requests.get, None))

            seq = 0

            def pose(ack: int = 0) -> pb.ClientMessage:
                nonlocal seq
                seq += 1
                return pose_message(k, seq, ack)

            def send_poses() -> None:
                while not stop.wait(1.0 / pose_hz):
                    requests.put(pose())
                requests.put(None)

            if pose_hz is None:
                requests.put(pose())
                threading.Timer(REFILL_SECONDS, lambda: requests.put(pose())).start()
            else:
                threading.Thread(target=send_poses, daemon=True).start()
            try:
                for msg in call:
                    if msg.WhichOneof("kind") == "frame" and not msg.frame.continued:
                        frames[k] += 1
                        if pose_hz is None:      # as fly_h2's on_message
                            requests.put(pose(ack=msg.frame.frame_seq))
                            if seq < msg.frame.pose_seq + 2:
                                threading.Timer(REFILL_SECONDS, lambda: requests.put(pose())).start()
                        else:
                            requests.put(pb.ClientMessage(ack=pb.Ack(frame_seq=msg.frame.frame_seq)))
                    if stop.is_set():
                        break
            except grpc.RpcError:
                pass
            finally:
                requests.put(None)
                call.cancel()

    threads = [threading.Thread(target=fly_h2, daemon=True)] if client == "h2" else \
        [threading.Thread(target=session, args=(k,), daemon=True) for k in range(2)]
    try:
        for th in threads:
            th.start()
        time.sleep(3.0)                                # both sessions open and refining
        m0, cpu0, me0, t0 = metrics(server.metrics_port), cpu_seconds(server.proc.pid), time.process_time(), \
            time.perf_counter()
        n0 = sum(frames)
        time.sleep(seconds)
        m1, cpu1, me1, t1 = metrics(server.metrics_port), cpu_seconds(server.proc.pid), time.process_time(), \
            time.perf_counter()
        n1 = sum(frames)
    finally:
        stop.set()
        for th in threads:
            th.join(30)
        server.stop()
    wall = t1 - t0
    refine = m1["caveclod_refine_cpu_seconds_total"] - m0["caveclod_refine_cpu_seconds_total"]
    updates = m1["caveclod_refine_seconds_count"] - m0["caveclod_refine_seconds_count"]
    busy = m1["caveclod_refine_seconds_sum"] - m0["caveclod_refine_seconds_sum"]
    return {"seconds": round(wall, 1), "sessions": 2, "server_transport": server_transport, "client": client,
            "pose_hz": pose_hz or "one per frame",
            "tolerance_px": tolerance_px, "viewport": f"{size[0]}x{size[1]}", "frames": n1 - n0, "updates": int(updates),
            "update_ms_mean": round(1e3 * busy / max(updates, 1), 1),
            "refine_cpu_cores": round(refine / wall, 2), "server_cpu_cores": round((cpu1 - cpu0) / wall, 2),
            "client_cpu_cores": round((me1 - me0) / wall, 2)}


def kernel_parallelism(mesh: Path, seconds: float) -> dict:
    """The refinement kernels alone, in this process: 1 then 2 threads, each a
    camera jumping between far poses, as in :func:`parallel_refinement`.
    Shows how much of two cores the GIL-free updates use with no encoding,
    network or client beside them."""
    import caveclod
    from caveclod.paths import flyover
    from caveclod.refine.view import View
    m = caveclod.load(mesh)
    lo, hi = mesh_bounds(mesh)
    out = {}
    for n in (1, 2):
        stop = threading.Event()
        tallies = [[0, 0.0] for _ in range(n)]          # updates, thread CPU seconds

        def run(k: int) -> None:
            cam = m.new_camera()
            t, i = 0.0, 0
            while not stop.is_set():
                t, i = 30.0 - t, i + 1
                view = View.from_pose(flyover(lo, hi, k, t + 0.001 * i), width=1280, height=720, tolerance_px=0.5)
                c0 = time.thread_time()
                cam.update(view)
                tallies[k][1] += time.thread_time() - c0
                tallies[k][0] += 1

        threads = [threading.Thread(target=run, args=(k,), daemon=True) for k in range(n)]
        for th in threads:
            th.start()
        time.sleep(1.0)                                  # past the first, full refinement
        base = [list(x) for x in tallies]
        t0 = time.perf_counter()
        time.sleep(seconds)
        wall = time.perf_counter() - t0
        done = [[a - b for a, b in zip(x, y)] for x, y in zip(tallies, base)]
        stop.set()
        for th in threads:
            th.join(30)
        updates = sum(d[0] for d in done)
        out[f"threads_{n}"] = {"updates_per_second": round(updates / wall, 1),
                               "refine_cpu_cores": round(sum(d[1] for d in done) / wall, 2)}
    out["speedup"] = round(out["threads_2"]["updates_per_second"] / out["threads_1"]["updates_per_second"], 2)
    return out


def mesh_bounds(mesh: Path) -> tuple:
    """(lo, hi) corners of a .cvc file's positions."""
    import caveclod
    m = caveclod.load(mesh)
    return tuple(float(v) for v in m.bounds()[0]), tuple(float(v) for v in m.bounds()[1])


def with_and_without_stored_packing(mesh: Path) -> tuple[Path, Path]:
    """``mesh`` with the packed downloads its build stores (added to a file built before they were),
    and a copy without them beside it (``NAME_bare.cvc``): a server of the copy packs at start."""
    import caveclod
    from caveclod import vertexpack
    m = caveclod.load(mesh)
    try:
        usable = all(vertexpack.stored_packed(m, bits, morph) is not None for bits, morph in vertexpack.STORED_VARIANTS)
    except ValueError:              # stored by an earlier format of the metadata
        usable = False
    if not usable:
        print(f"storing the packed downloads in {mesh} ...", file=sys.stderr)
        vertexpack.attach_packed(m)
        m.save(mesh)
    bare = mesh.with_name(mesh.stem + "_bare.cvc")
    if not bare.exists() or caveclod.load(bare).content_hash != m.content_hash:
        m.attachments = {}
        m.save(bare)
    return mesh, bare


def start_once(mesh: Path, cache_dir: Path, checked_dir: str = "none") -> dict:
    """One server start (``--checked-dir checked_dir``): seconds to health SERVING and to the first
    frame of a session whose client holds the vertex buffer (in ``cache_dir``), from the process's
    start; then seconds from a fresh client's Open (no buffer: it downloads and decodes it) to its
    first frame."""
    import tempfile

    import grpc
    from grpc_health.v1 import health_pb2, health_pb2_grpc

    from caveclod.client import Client
    t0 = time.perf_counter()
    proc = subprocess.Popen([sys.executable, "-m", "caveclod.cli", "serve", str(mesh), "--host", "127.0.0.1",
                             "--port", "0", "--checked-dir", checked_dir],
                            stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    try:
        port = int(proc.stdout.readline().rsplit(":", 1)[1])
        with grpc.insecure_channel(f"127.0.0.1:{port}") as channel:
            stub = health_pb2_grpc.HealthStub(channel)
            for _ in range(100_000):
                try:
                    if stub.Check(health_pb2.HealthCheckRequest(), timeout=1).status == 1:
                        break
                except grpc.RpcError:
                    time.sleep(0.005)
        out = {"health_serving_s": time.perf_counter() - t0}
        with Client(f"127.0.0.1:{port}", cache_dir=cache_dir) as client:
            with client.session(mesh.stem, width=1280, height=720) as s:
                s.next_frame(timeout=120)
        out["first_frame_s"] = time.perf_counter() - t0
        with tempfile.TemporaryDirectory() as empty, Client(f"127.0.0.1:{port}", cache_dir=empty) as client:
            t1 = time.perf_counter()
            with client.session(mesh.stem, width=1280, height=720) as s:
                s.next_frame(timeout=120)
            out["fresh_client_first_frame_s"] = time.perf_counter() - t1
        return out
    finally:
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(30)


def startup(mesh: Path, repeats: int = 5) -> dict:
    """:func:`start_once` ``repeats`` times for the file as built (its packed downloads stored) and
    for a copy without them (as files built before they were stored), each checked at start
    (``--checked-dir none``) and remembered as checked by an earlier start (``_remembered``: a
    restart), interleaved; medians and all runs. An untimed start of each first fills the holding
    client's cache and the remembered checks."""
    import tempfile
    files = dict(zip(("stored", "packed_at_start"), with_and_without_stored_packing(mesh)))
    runs = {f"{name}{how}": [] for name in files for how in ("", "_remembered")}
    with tempfile.TemporaryDirectory() as cache_dir, tempfile.TemporaryDirectory() as checked:
        for r in range(repeats + 1):
            for name, path in files.items():
                for how, checked_dir in (("", "none"), ("_remembered", checked)):
                    run = start_once(path, Path(cache_dir), checked_dir)
                    if r:
                        runs[f"{name}{how}"].append(run)
    out = {"mesh": mesh.name, "repeats": repeats}
    for name, done in runs.items():
        out[name] = {key: round(statistics.median(run[key] for run in done), 3) for key in done[0]}
        out[name]["all"] = [{key: round(v, 3) for key, v in run.items()} for run in done]
    return out


def shared_mesh(mesh: Path, sessions: int, duration: float) -> dict:
    """Two server processes mapping the same .cvc, ``sessions`` sessions each at once: how much of each
    one's resident mesh pages is its own (proportional: MeshPss) against what it maps (MeshRss)."""
    servers = [Server(mesh, "--max-sessions", str(max(64, sessions))) for _ in range(2)]
    try:
        samplers = [Sampler(s) for s in servers]
        threads = [threading.Thread(target=loadtest, args=(s.port, sessions, duration)) for s in servers]
        for t in threads:
            t.start()
        time.sleep(duration * 0.8)
        during = [memory(s.proc.pid) for s in servers]
        for t in threads:
            t.join(duration + 150)
        for sm in samplers:
            sm.stop()
    finally:
        for s in servers:
            s.stop()
    MiB = 1 << 20
    return {"mesh": mesh.name, "mesh_file_mib": round(mesh.stat().st_size / MiB, 1), "sessions_per_server": sessions,
            "servers": [{"private_mib": round(m.get("RssAnon", 0) / MiB, 1),
                         "mesh_resident_mib": round(m["MeshRss"] / MiB, 1),
                         "mesh_proportional_mib": round(m["MeshPss"] / MiB, 1),
                         "files_resident_mib": round(m.get("RssFile", 0) / MiB, 1)} for m in during]}


MEDIAN_KEYS = ("p50", "p99", "frames_per_second", "steady_server_refine_ms_per_frame",
               "steady_server_other_ms_per_frame", "server_refine_ms_per_frame", "server_other_ms_per_frame",
               "client_cpu_ms_per_frame", "bytes_per_frame",
               "bytes_per_changed_triangle", "bytes_per_changed_triangle_steady", "server_cpu_cores",
               "client_cpu_cores", "other_cpu_cores", "divergences")


def medians(runs: list, rows: bool = False) -> list:
    """Per load level, the median over repeats of each figure of MEDIAN_KEYS (``rows``: shaped like
    a run, latency_ms and per-frame keys where :func:`plot` reads them)."""
    out = []
    for n in sorted({r["sessions"] for r in runs}):
        mine = [r for r in runs if r["sessions"] == n]
        flat = [{**r, **{k: r["latency_ms"][k] for k in ("p50", "p99")}} for r in mine]
        row = {"sessions": n, "repeats": len(mine)}
        for k in MEDIAN_KEYS:
            values = [f[k] for f in flat if f.get(k) is not None]
            row[k] = round(statistics.median(values), 3) if values else None
        row["errors"] = sum(sum(r["errors"].values()) for r in mine)
        if rows:
            row["latency_ms"] = {"p50": row["p50"], "p99": row["p99"]}
        out.append(row)
    return out


def _server_ms_per_frame(r: dict, kind: str) -> float:
    """The server's CPU a frame (``kind`` "refine" or "other") in steady state, or over the whole
    run where a run was too short for a steady window (the key is then absent, or None in medians)."""
    steady = r.get(f"steady_server_{kind}_ms_per_frame")
    return steady if steady is not None else r[f"server_{kind}_ms_per_frame"]


def plot(levels: list, path: Path, others: dict | None = None, summary: list | None = None) -> None:
    """Latency CDFs of ``levels`` (this server, one repeat); p50/p99, server and load-generator CPU per frame against
    sessions for it (``summary``: medians over repeats, else ``levels``) and for ``others``
    ({name: rows}: a baseline checkout, several processes)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, (ax, bx, cx, dx) = plt.subplots(1, 4, figsize=(20, 4))
    for r in levels:
        lat = np.sort(np.asarray(r["latencies_ms"]))
        if len(lat):
            ax.plot(lat, np.arange(1, len(lat) + 1) / len(lat), label=f"{r['sessions']} sessions")
    ax.axvline(50, ls="--", color="grey", lw=0.8)
    ax.set_xscale("log")
    ax.set_xlabel("pose -> frame latency (ms, log)")
    ax.set_ylabel("fraction of poses")
    ax.set_title("this server", fontsize=9)
    ax.legend(fontsize=7)
    ax.grid(alpha=0.3)
    series = {"this": summary or levels, **(others or {})}
    for k, (name, rs) in enumerate(series.items()):
        n = [r["sessions"] for r in rs]
        colour = f"C{k}"
        bx.plot(n, [r["latency_ms"]["p99"] for r in rs], "o-", color=colour, label=f"{name} p99")
        bx.plot(n, [r["latency_ms"]["p50"] for r in rs], "o:", color=colour, label=f"{name} p50")
        refine = [_server_ms_per_frame(r, "refine") for r in rs]
        other = [_server_ms_per_frame(r, "other") for r in rs]
        cx.plot(n, [a + b for a, b in zip(refine, other)], "o-", color=colour, label=f"{name}: all")
        cx.plot(n, other, "o:", color=colour, label=f"{name}: outside refinement")
        dx.plot(n, [r["client_cpu_ms_per_frame"] for r in rs], "o-", color=colour, label=name)
    bx.axhline(50, ls="--", color="grey", lw=0.8)
    bx.set_yscale("log")
    bx.set_xlabel("sessions at 30 Hz (one camera each)")
    bx.set_ylabel("pose -> frame latency (ms, log)")
    bx.legend(fontsize=7)
    bx.grid(alpha=0.3)
    cx.set_xlabel("sessions at 30 Hz (one camera each)")
    cx.set_ylabel("server CPU per frame, steady state (ms)")
    cx.set_ylim(bottom=0)
    cx.legend(fontsize=7)
    cx.grid(alpha=0.3)
    dx.set_xlabel("sessions at 30 Hz (one camera each)")
    dx.set_ylabel("load generator CPU per frame (ms)")
    dx.set_ylim(bottom=0)
    dx.legend(fontsize=7)
    dx.grid(alpha=0.3)
    fig.suptitle("caveclod serve, 1M-triangle terrain, 1280x720, 1 px, flyover; server and load generator "
                 "on one 2-core machine", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--size", type=int, default=708, help="default terrain size (708: 1,002,528 triangles)")
    ap.add_argument("--sessions", default="8,16,32,48", help="load levels, comma-separated")
    ap.add_argument("--duration", type=float, default=20.0, help="seconds of poses per load level")
    ap.add_argument("--parallel-seconds", type=float, default=10.0)
    ap.add_argument("--parallel-client", default="h2",
                    help="the parallel-refinement runs' client: h2 (one event loop over caveclod's HTTP/2 client, "
                         "the default), grpc (a blocking gRPC stream a session), or both, comma-separated")
    ap.add_argument("--startup-size", type=int, default=1024, help="mesh of the start-up test (1024: 2M triangles)")
    ap.add_argument("--startup-mesh", metavar="CVC", help="a .cvc of the start-up test instead of the built-in "
                    "terrain at --startup-size (e.g. benchmarks/large_dem.py's model built with --stride)")
    ap.add_argument("--startup-repeats", type=int, default=5, help="starts of each kind, after an untimed one")
    ap.add_argument("--skip", default="", help="comma-separated sections to skip: capacity,parallel,startup,shared")
    ap.add_argument("--shared-sessions", type=int, default=8,
                    help="sessions on each of the two servers of the shared-mesh section (default 8)")
    ap.add_argument("--out", default=str(RESULTS / "service.json"), help="the JSON report (default results/service.json)")
    ap.add_argument("--loadtest-processes", type=int, default=1,
                    help="processes of caveclod loadtest (its --processes; default 1)")
    ap.add_argument("--frame-encoding", default="linked",
                    help="the load test's --frame-encoding (linked, ops, raw; default linked); several, "
                         "comma-separated, measure this server under each at each level, interleaved "
                         "(capacity_encoding_<encoding>)")
    ap.add_argument("--repeats", type=int, default=1,
                    help="runs of each load level and server, interleaved; the summary holds their medians")
    ap.add_argument("--connections", type=int, default=4,
                    help="connections the load test's sessions share (its --connections; default 4: enough for "
                         "a server of several processes to spread, cheaper for the generator than one a session)")
    ap.add_argument("--server-processes", type=int, default=1,
                    help="also measure the server as N processes (caveclod serve --processes N) at each level")
    ap.add_argument("--loadtest-transport", default="auto",
                    help="the load test's --transport (h2, grpc, auto: h2 where installed); several, comma-separated, "
                         "measure this server under each load generator at each level, interleaved "
                         "(capacity_loadtest_<transport>)")
    ap.add_argument("--loadtest-decoder", default="auto",
                    help="the load test's --decoder (compiled, numpy, auto: compiled where numba is installed); "
                         "several, comma-separated, measure this server under each at each level, interleaved "
                         "(capacity_decoder_<decoder>)")
    ap.add_argument("--server-transport", default="grpc",
                    help="caveclod serve --transport of the servers measured, comma-separated (grpc,h2: both, "
                         "interleaved at each level; the first is the one reported as 'this')")
    ap.add_argument("--baseline", metavar="DIR",
                    help="a checkout of an older caveclod (e.g. git worktree add DIR REV): its server is measured "
                         "right after ours at each load level, as capacity_baseline")
    args = ap.parse_args()
    skip = set(filter(None, args.skip.split(",")))
    mesh = mesh_path(args.size)
    path = Path(args.out)
    out = json.loads(path.read_text()) if skip and path.exists() else {}     # keep the sections not re-run
    out.update({"mesh": f"default --size {args.size}", "machine_cores": os.cpu_count()})
    if "capacity" not in skip:
        levels, baseline = [], []
        transports = args.loadtest_transport.split(",")
        kinds = args.server_transport.split(",")           # serve --transport: the first is "this"
        decoders = args.loadtest_decoder.split(",")
        encodings = args.frame_encoding.split(",")
        # (name, the list its runs go to, capacity()'s keywords): this server, then each
        # variant of it that the options ask for, measured at every level in turn.
        this = {"command": None, "server_processes": 1, "transport": transports[0], "server_transport": kinds[0],
                "decoder": decoders[0], "encoding": encodings[0]}
        servers = [("this", levels, this)]

        def variant(name: str, into: list, **changes) -> None:
            servers.append((name, into, {**this, **changes}))

        by_transport = {t: [] for t in transports[1:]}
        for t in transports[1:]:            # the same server under another load generator
            variant(f"this, loadtest {t}", by_transport[t], transport=t)
        by_decoder = {d: [] for d in decoders[1:]}
        for d in decoders[1:]:              # the same server, the load generator decoding otherwise
            variant(f"this, loadtest --decoder {d}", by_decoder[d], decoder=d)
        by_encoding = {e: [] for e in encodings[1:]}
        for e in encodings[1:]:             # the same server, the sessions asking for another frame encoding
            variant(f"this, --frame-encoding {e}", by_encoding[e], encoding=e)
        by_kind = {k: [] for k in kinds[1:]}
        for k in kinds[1:]:                 # the same server over another transport
            variant(f"serve --transport {k}", by_kind[k], server_transport=k)
        multi = {k: [] for k in kinds}
        if args.server_processes > 1:       # the same server as N processes (caveclod serve --processes N)
            for k in kinds:
                variant(f"processes {args.server_processes}" + (f", --transport {k}" if len(kinds) > 1 else ""),
                        multi[k], server_processes=args.server_processes, server_transport=k)
        if args.baseline:          # an older checkout's server, run right after ours at each level
            variant("baseline", baseline, server_transport="grpc",
                    command=[sys.executable, "-c", "import sys; sys.path.insert(0, sys.argv.pop(1)); "
                             "from caveclod.cli import main; sys.exit(main())", args.baseline, "serve"])
        for repeat in range(args.repeats):       # interleaved: the machine's drift hits every server alike
            for n in (int(x) for x in args.sessions.split(",")):
                for name, into, how in servers:
                    r = capacity(mesh, n, args.duration, processes=args.loadtest_processes,
                                 connections=args.connections, **how)
                    r.update(server=name, repeat=repeat)
                    into.append(r)
                    print(f"{name} {n:3d} sessions: p50 {r['latency_ms']['p50']} ms  p99 {r['latency_ms']['p99']} ms  "
                          f"{r['frames_per_second']} frames/s  {r['bytes_per_frame']} B/frame  "
                          f"{r['bytes_per_changed_triangle']} B/changed tri ({r['bytes_per_changed_triangle_steady']} "
                          f"steady)  divergences {r['divergences']}  errors {r['errors']}  cpu: server "
                          f"{r['server_cpu_cores']} (refine {r['server_refine_cpu_cores']}; per frame "
                          f"{r['server_refine_ms_per_frame']} + {r['server_other_ms_per_frame']} ms; steady "
                          f"{r.get('steady_server_refine_ms_per_frame')} + {r.get('steady_server_other_ms_per_frame')}"
                          f" ms), loadtest "
                          f"{r['client_cpu_cores']} ({r['client_cpu_ms_per_frame']} ms a frame), others "
                          f"{r['other_cpu_cores']}", file=sys.stderr)
        out["summary"] = {name: medians(into) for name, into, _ in servers}
        plot([r for r in levels if r["repeat"] == 0], path.with_name(f"{path.stem}_latency.png"),
             {name: medians(into, rows=True) for name, into, _ in servers[1:]}, medians(levels, rows=True))
        for name, rows in out["summary"].items():
            for row in rows:
                print(f"median {name} {row['sessions']:3d}: {row}", file=sys.stderr)
        for r in levels + baseline + sum(multi.values(), []) + sum(by_transport.values(), []) \
                + sum(by_kind.values(), []) + sum(by_decoder.values(), []) + sum(by_encoding.values(), []):
            r.pop("latencies_ms", None)
        out["capacity"] = levels
        for k, rows in multi.items():
            if rows:
                out["capacity_processes" + ("" if k == kinds[0] else f"_{k}")] = {
                    "processes": args.server_processes, "transport": k, "levels": rows}
        for t, rows in by_transport.items():
            out[f"capacity_loadtest_{t}"] = rows
        for k, rows in by_kind.items():
            out[f"capacity_transport_{k}"] = rows
        for d, rows in by_decoder.items():
            out[f"capacity_decoder_{d}"] = rows
        for e, rows in by_encoding.items():
            out[f"capacity_encoding_{e}"] = rows
        if baseline:
            out["capacity_baseline"] = {"checkout": args.baseline, "levels": baseline}
    if "parallel" not in skip:
        # The timer client of earlier runs, then a client that keeps one pose
        # waiting, over updates growing with a finer tolerance and a larger view;
        # each client kind of --parallel-client in turn.
        kind = args.server_transport.split(",")[0]
        runs = []
        for client in args.parallel_client.split(","):
            runs.append(parallel_refinement(mesh, args.parallel_seconds, server_transport=kind, client=client))
            for tolerance, size in ((0.5, (1280, 720)), (0.25, (1920, 1080)), (0.1, (1920, 1080))):
                runs.append(parallel_refinement(mesh, args.parallel_seconds, pose_hz=None, tolerance_px=tolerance,
                                                size=size, server_transport=kind, client=client))
        out["parallel_refinement"] = runs
        for r in runs:
            print(f"parallel refinement: {r}", file=sys.stderr)
        out["kernel_parallelism"] = kernel_parallelism(mesh, args.parallel_seconds)
        print(f"kernels alone: {out['kernel_parallelism']}", file=sys.stderr)
    if "startup" not in skip:
        out["startup"] = startup(Path(args.startup_mesh) if args.startup_mesh else mesh_path(args.startup_size),
                                 repeats=args.startup_repeats)
        print(f"start-up: {out['startup']}", file=sys.stderr)
    if "shared" not in skip:
        out["shared_mesh"] = shared_mesh(mesh, args.shared_sessions, args.duration)
        print(f"shared mesh: {out['shared_mesh']}", file=sys.stderr)
    RESULTS.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(out, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
