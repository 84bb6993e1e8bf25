"""A fresh client's first session on a large mesh: seconds from Open to the first frame and the
client's peak memory, for several checkouts' clients against one server, interleaved.

A client that holds no vertex buffer downloads the packed buffer and decodes
it (caveclod.vertexpack), checks it and writes its disk cache before the
first frame. Each repeat runs every checkout's client once, in a process of
its own with a fresh cache directory (its peak RSS is its own), against the
same ``caveclod serve`` of the mesh (this checkout's server):

    .venv/bin/python benchmarks/client_download.py --size 4096 --checkouts DIR1 DIR2 .

DIRs are checkouts of other revisions (``git worktree add DIR REV``); ``.``
is this one. Writes benchmarks/results/client_download.json and .png.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import statistics
import subprocess
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))
from service import mesh_path  # noqa: E402

RESULTS = Path(__file__).parent / "results"
ROOT = Path(__file__).resolve().parent.parent

# Run in the client's process: its first frame, timed from Open, and its peak RSS.
CLIENT = r"""
import resource, sys, tempfile, time
root, port, mesh = sys.argv[1:4]
sys.path.insert(0, root)
import caveclod.client
from caveclod.client import Client
assert caveclod.client.__file__.startswith(root), caveclod.client.__file__
with tempfile.TemporaryDirectory() as cache, Client(f"127.0.0.1:{port}", cache_dir=cache) as client:
    t = time.perf_counter()
    with client.session(mesh, width=1280, height=720) as s:
        s.next_frame(timeout=300)
        print(time.perf_counter() - t, resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024)
"""


def git_revision(path: Path) -> str:
    out = subprocess.run(["git", "-C", str(path), "describe", "--always", "--dirty"], capture_output=True, text=True)
    return out.stdout.strip() or "?"


def first_session(root: Path, port: int, mesh: str) -> tuple[float, int]:
    """(seconds from Open to the first frame, peak RSS bytes) of a fresh client of ``root``'s checkout."""
    out = subprocess.run([sys.executable, "-c", CLIENT, str(root), str(port), mesh], capture_output=True,
                         text=True, timeout=600, cwd=root)
    if out.returncode:
        raise RuntimeError(f"the client of {root} failed: {out.stderr[-800:]}")
    seconds, rss = out.stdout.split()
    return float(seconds), int(rss)


def plot(report: dict, path: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    rows = report["checkouts"]
    fig, (a, b) = plt.subplots(1, 2, figsize=(9, 3.4))
    labels = [r["revision"] for r in rows]
    for k, r in enumerate(rows):
        a.scatter([k] * len(r["seconds_all"]), r["seconds_all"], s=14, color="C0")
        b.scatter([k] * len(r["peak_rss_gb_all"]), r["peak_rss_gb_all"], s=14, color="C1")
    a.plot(range(len(rows)), [r["seconds"] for r in rows], "C0-", label="median")
    b.plot(range(len(rows)), [r["peak_rss_gb"] for r in rows], "C1-", label="median")
    a.set_ylabel("Open -> first frame (s)")
    b.set_ylabel("client peak RSS (GB)")
    for ax in (a, b):
        ax.set_xticks(range(len(rows)), labels)
        ax.set_ylim(bottom=0)
        ax.grid(alpha=0.3)
    fig.suptitle(f"a fresh client's first session on {report['mesh']} ({report['vertices']:,} vertices)", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--size", type=int, default=4096, help="the default terrain's size (4096: 33.5M triangles)")
    ap.add_argument("--checkouts", nargs="+", default=["."], help="checkouts whose clients are measured")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--out", default=str(RESULTS / "client_download.json"))
    args = ap.parse_args()
    import caveclod
    mesh = mesh_path(args.size)
    roots = [Path(c).resolve() for c in args.checkouts]
    server = subprocess.Popen([sys.executable, "-m", "caveclod.cli", "serve", str(mesh), "--host", "127.0.0.1",
                               "--port", "0"], stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True,
                              cwd=ROOT)
    runs = {root: [] for root in roots}
    try:
        port = int(server.stdout.readline().rsplit(":", 1)[1])
        for _ in range(args.repeats):
            for root in roots:
                runs[root].append(first_session(root, port, mesh.stem))
                print(f"{root}: {runs[root][-1]}", file=sys.stderr)
    finally:
        os.kill(server.pid, signal.SIGTERM)
        server.wait(60)
    report = {"mesh": mesh.name, "vertices": caveclod.load(mesh).n_vertices, "repeats": args.repeats, "checkouts": [
        {"checkout": str(root), "revision": git_revision(root),
         "seconds": round(statistics.median(s for s, _ in done), 2), "seconds_all": [round(s, 2) for s, _ in done],
         "peak_rss_gb": round(statistics.median(r for _, r in done) / 1e9, 2),
         "peak_rss_gb_all": [round(r / 1e9, 2) for _, r in done]} for root, done in runs.items()]}
    out = Path(args.out)
    out.write_text(json.dumps(report, indent=1) + "\n")
    plot(report, out.with_suffix(".png"))
    for row in report["checkouts"]:
        print(f"{row['revision']}: {row['seconds']} s, {row['peak_rss_gb']} GB", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
