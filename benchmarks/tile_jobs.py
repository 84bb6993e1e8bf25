"""Tile jobs and their merge against one process: time, peak memory, bytes, the same mesh.

    python benchmarks/tile_jobs.py [--terrain default] [--sizes 1448] [--jobs 2 8] [--workers 2]

For each size, in fresh processes through the command line, one after the
other on this machine: ``caveclod build`` in one process; then for each job
count N, the N tile jobs (``--tile-job I/N --tiles-dir DIR``) and the merge
(``--tiles-dir DIR -o``). Reported: each process's build seconds (from its
JSON report: the jobs' ``seconds``, the builds' ``build_seconds``), its
peak resident memory (VmHWM), the blocks' level and bytes on disk, whether
the merged mesh's content hash equals the single build's, and the build
time machines running the jobs at once would take (the slowest job plus the
merge) against one machine's. Writes ``benchmarks/results/tile_jobs.json``
and a plot.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

RESULTS = Path(__file__).parent / "results"
HERE = Path(__file__).resolve().parents[1]

CHILD = r"""
import contextlib, io, json, sys
from caveclod import cli
out = io.StringIO()
with contextlib.redirect_stdout(out):
    rc = cli.main(sys.argv[1:])
peak = next(int(l.split()[1]) for l in open("/proc/self/status") if l.startswith("VmHWM:"))
print(json.dumps({"rc": rc, "report": json.loads(out.getvalue()), "peak_bytes": peak * 1024}))
"""


def run_cli(*args) -> dict:
    """``caveclod ARGS --json --quiet`` in a fresh process: its report and peak memory."""
    proc = subprocess.run([sys.executable, "-c", CHILD, *map(str, args), "--json", "--quiet"], capture_output=True,
                          text=True, cwd=HERE, env={**os.environ, "PYTHONPATH": str(HERE)})
    if proc.returncode != 0:
        raise SystemExit(f"caveclod {' '.join(map(str, args))} failed:\n{proc.stderr}")
    return json.loads(proc.stdout.strip().splitlines()[-1])


def measure(terrain: str, size: int, jobs: list[int], workers: int, scratch: Path) -> dict:
    common = ["build", terrain, "--size", size, "--workers", workers]
    single = run_cli(*common, "-o", scratch / "single.cvc")
    row = {"terrain": terrain, "size": size, "triangles": single["report"]["faces"], "workers": workers,
           "single": {"build_seconds": single["report"]["build_seconds"], "peak_bytes": single["peak_bytes"]},
           "jobs": []}
    for n in jobs:
        where = scratch / f"tiles-{n}"
        runs = [run_cli(*common, "--tiles-dir", where, "--tile-job", f"{i}/{n}") for i in range(n)]
        blocks = sum(f.stat().st_size for f in where.glob("*.npz"))
        merge = run_cli(*common, "--tiles-dir", where, "-o", scratch / f"merged-{n}.cvc")
        job_seconds = [r["report"]["seconds"] for r in runs]
        row["jobs"].append({
            "jobs": n, "block_level": runs[0]["report"]["block_level"],
            "blocks": sum(r["report"]["blocks_written"] for r in runs),
            "job_seconds": job_seconds, "job_peak_bytes": [r["peak_bytes"] for r in runs],
            "block_bytes": blocks, "merge_build_seconds": merge["report"]["build_seconds"],
            "merge_peak_bytes": merge["peak_bytes"],
            "same_mesh": merge["report"]["content_hash"] == single["report"]["content_hash"],
            "machines_seconds": max(job_seconds) + merge["report"]["build_seconds"],
        })
        shutil.rmtree(where)
        print(f"{terrain} {size}: {n} jobs (level {row['jobs'][-1]['block_level']}): jobs "
              f"{min(job_seconds):.1f}-{max(job_seconds):.1f} s, merge {merge['report']['build_seconds']:.1f} s, "
              f"one process {single['report']['build_seconds']:.1f} s, same mesh: {row['jobs'][-1]['same_mesh']}",
              flush=True)
    return row


def plot(rows: list[dict], path: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(1, len(rows), figsize=(5 * len(rows), 4), squeeze=False)
    for ax, row in zip(axes[0], rows):
        labels = ["one process"] + [f"{j['jobs']} jobs" for j in row["jobs"]]
        slowest = [0.0] + [max(j["job_seconds"]) for j in row["jobs"]]
        merge = [row["single"]["build_seconds"]] + [j["merge_build_seconds"] for j in row["jobs"]]
        ax.bar(labels, slowest, label="slowest job")
        ax.bar(labels, merge, bottom=slowest, label="merge (or the whole build)")
        ax.set_ylabel("build seconds")
        ax.set_title(f"{row['terrain']} {row['triangles'] / 1e6:.1f}M triangles")
        ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=100)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--terrain", default="default", choices=["default", "rough"])
    ap.add_argument("--sizes", type=int, nargs="+", default=[1448], help="cells per side (1448: 4.2M triangles)")
    ap.add_argument("--jobs", type=int, nargs="+", default=[2, 8], help="job counts to try")
    ap.add_argument("--workers", type=int, default=2, help="threads of every process")
    ap.add_argument("--out", type=Path, default=RESULTS / "tile_jobs.json")
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="caveclod-tile-jobs-") as scratch:
        rows = [measure(args.terrain, size, args.jobs, args.workers, Path(scratch)) for size in args.sizes]
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps({"rows": rows, "cpus": os.cpu_count()}, indent=1))
    plot(rows, args.out.with_suffix(".png"))
    print(f"wrote {args.out} and {args.out.with_suffix('.png')}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
