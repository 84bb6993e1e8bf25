"""Reading a strided GeoTIFF by window against reading it whole: seconds and peak memory.

``caveclod build big.tif --stride K`` reads only the strips or tiles that
hold a kept sample, and keeps only the kept samples
(:mod:`caveclod.builder.rasterwindow`); before, the file was read whole and
then strided. Each run is a fresh process that reads the file and makes the
build's input mesh (:func:`caveclod.api.to_source`), the step the window
changes; its peak resident memory is the process's ``ru_maxrss``.

    .venv/bin/python benchmarks/large_dem.py --side 19999 --out /tmp/dem20k.tif      # 1.6 GB, 2 minutes
    .venv/bin/python benchmarks/read_window.py /tmp/dem20k.tif --stride 8 --repeats 3
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
from pathlib import Path

RESULTS = Path(__file__).resolve().parent / "results"

_CHILD = """
import json, resource, sys, time
from caveclod.api import to_source
from caveclod.builder import terrain
path, stride, how = sys.argv[1], int(sys.argv[2]), sys.argv[3]
if how == "whole":                       # the reading before: the whole file, then every stride-th sample
    read = terrain.read_heightfield
    terrain.read_heightfield = lambda p, window=False: read(p, window=False)
t = time.perf_counter()
src = to_source(path, stride=stride)
peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
print(json.dumps({"seconds": time.perf_counter() - t, "peak_mb": peak_mb, "triangles": len(src.faces)}))
"""


def run(path: str, stride: int, how: str) -> dict:
    out = subprocess.run([sys.executable, "-c", _CHILD, path, str(stride), how], capture_output=True, text=True,
                         check=True, timeout=3600)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("tiff")
    ap.add_argument("--stride", type=int, default=8)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--out", default=str(RESULTS / "read_window.json"))
    args = ap.parse_args()
    runs = {"window": [], "whole": []}
    for _ in range(args.repeats):                 # alternated, so that neither gets the warmer page cache
        for how in runs:
            runs[how].append(run(args.tiff, args.stride, how))
            print(how, runs[how][-1], flush=True)
    result = {"file": os.path.basename(args.tiff), "file_bytes": os.path.getsize(args.tiff), "stride": args.stride,
              "repeats": args.repeats, "triangles": runs["window"][0]["triangles"],
              **{how: {"seconds_median": statistics.median(r["seconds"] for r in rs),
                       "peak_mb_median": statistics.median(r["peak_mb"] for r in rs), "runs": rs}
                 for how, rs in runs.items()}}
    Path(args.out).write_text(json.dumps(result, indent=1) + "\n")
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(1, 2, figsize=(8, 3.2))
    for ax, key, label in zip(axes, ("seconds_median", "peak_mb_median"), ("seconds", "peak resident, MB")):
        ax.bar(list(runs), [result[how][key] for how in runs], color=["tab:green", "tab:grey"])
        ax.set_ylabel(label)
    fig.suptitle(f"{result['file']} ({result['file_bytes'] / 1e9:.1f} GB) at --stride {args.stride}: "
                 f"medians of {args.repeats}", fontsize=9)
    fig.tight_layout()
    fig.savefig(Path(args.out).with_suffix(".png"), dpi=110)
    print(json.dumps({how: {k: round(v, 2) for k, v in result[how].items() if k != "runs"} for how in runs}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
