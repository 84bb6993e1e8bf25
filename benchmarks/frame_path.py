"""Where a frame's server CPU goes, outside gRPC: the session code in one process, no sockets.

    python benchmarks/frame_path.py [--size 708] [--sessions 16] [--frames 300] [--repeats 3]

N one-camera sessions of ``caveclod serve``'s own classes (``Session``, the
catalogue, the metrics) fly the flyover at 30 Hz on the 1M-triangle default
terrain, 1280x720, 1 px, op streams, each frame made as the server makes it:
the pose's bytes parsed (``wire.parse_client_message``) and accepted
(``Session.accept``, with the ack it carries) and the session polled; then
``Session.make_frame`` (refinement, the delta, checksums, the op stream,
the frame's bytes). Thread CPU time of each step per frame, the update's
own share (``CameraState.update_params``: the kernels and the Python around
them) split off; medians over ``--repeats`` runs after a first second of
refining up from the base mesh. Together with the whole server's CPU per
frame (``benchmarks/service.py``) and gRPC's own floor
(``benchmarks/server_model.py``, model ``floor``) this is the README's
breakdown. Writes ``benchmarks/results/frame_path.json`` and ``frame_path.png``.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))
from service import RESULTS, mesh_path  # noqa: E402


def run(mesh: Path, sessions: int, frames: int) -> dict:
    from caveclod import wire
    from caveclod.paths import pose
    from caveclod.refine.camera import CameraState
    from caveclod.server.meshes import Catalogue
    from caveclod.server.metrics import Metrics
    from caveclod.server.session import Session
    from caveclod.v1 import caveclod_pb2 as pb

    served = next(iter(Catalogue([str(mesh)]).meshes.values()))
    lo, hi = served.mesh.bounds()
    view = {"fov_y": 60.0, "width": 1280, "height": 720, "tolerance_px": 1.0, "cull": True, "backface": False}
    metrics = Metrics()
    group = [Session(f"s{i}", served, view, (None, None), 1, 4, 0.05, metrics,
                     frame_encoding=pb.FRAME_ENCODING_OPS) for i in range(sessions)]
    generations = [s.attach(0) for s in group]
    spent = {"parse_accept_poll": 0.0, "make_frame": 0.0, "update": 0.0}
    original = CameraState.update_params

    def timed_update(self, vp):
        t = time.thread_time()
        try:
            return original(self, vp)
        finally:
            spent["update"] += time.thread_time() - t

    CameraState.update_params = timed_update
    made = nbytes = 0
    try:
        for f in range(30 + frames):
            if f == 30:                            # the first second refines up from the base mesh
                spent = dict.fromkeys(spent, 0.0)
                made = nbytes = 0
            for i, s in enumerate(group):
                p = pose("flyover", lo, hi, i, f / 30.0)
                data = pb.ClientMessage(pose=pb.CameraPose(
                    camera=0, pose_seq=s.last_pose_seq + 1, eye=wire.vec3(p.eye), target=wire.vec3(p.target),
                    up=wire.vec3(p.up), ack_frame_seq=s.frame_seq)).SerializeToString()
                t0 = time.thread_time()
                s.accept(wire.parse_client_message(data), generations[i], wake=False)
                s.poll(generations[i], lambda: False)
                t1 = time.thread_time()
                parts = s.make_frame(generations[i])
                t2 = time.thread_time()
                spent["parse_accept_poll"] += t1 - t0
                spent["make_frame"] += t2 - t1
                made += 1
                nbytes += sum(len(x) for x in parts)
    finally:
        CameraState.update_params = original
    ms = {k: 1e3 * v / made for k, v in spent.items()}
    return {"frames": made, "bytes_per_frame": round(nbytes / made, 1),
            "parse_accept_poll_ms": ms["parse_accept_poll"], "update_ms": ms["update"],
            "frame_rest_ms": ms["make_frame"] - ms["update"]}


def plot(summary: dict, path: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    parts = [("update_ms", "refinement (update)"), ("frame_rest_ms", "delta, checksums, op stream, frame bytes"),
             ("parse_accept_poll_ms", "pose parsed, accepted, session polled")]
    fig, ax = plt.subplots(figsize=(10, 2.0))
    left = 0.0
    for key, label in parts:
        ax.barh([0], [summary[key]], left=left, label=f"{label}: {summary[key]:.3f} ms")
        left += summary[key]
    ax.set_yticks([])
    ax.set_xlabel("server CPU per frame outside gRPC (ms, median)")
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--size", type=int, default=708)
    ap.add_argument("--sessions", type=int, default=16)
    ap.add_argument("--frames", type=int, default=300, help="frames per session after the first second")
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    runs = [run(mesh_path(args.size), args.sessions, args.frames) for _ in range(args.repeats)]
    summary = {k: round(statistics.median(r[k] for r in runs), 4) for k in runs[0]}
    summary["total_ms"] = round(summary["update_ms"] + summary["frame_rest_ms"] + summary["parse_accept_poll_ms"], 4)
    print(json.dumps(summary), file=sys.stderr)
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / "frame_path.json").write_text(json.dumps({"sessions": args.sessions, "summary": summary,
                                                         "runs": runs}, indent=1) + "\n")
    plot(summary, RESULTS / "frame_path.png")
    return 0


if __name__ == "__main__":
    sys.exit(main())
