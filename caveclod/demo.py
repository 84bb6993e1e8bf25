"""``make demo``: build the built-in terrain and show what the build made.

Runs with no data and no network: ``python -m caveclod.demo [--size N]``.
"""

from __future__ import annotations

import argparse
import os
import sys

from .api import build, load


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m caveclod.demo", description=__doc__)
    ap.add_argument("--size", type=int, default=256, help="cells per side of the default terrain")
    ap.add_argument("--out", default="out/default.cvc", help="where to write the .cvc file")
    args = ap.parse_args(argv)
    os.makedirs(os.path.dirname(args.out) or ".", exist_ok=True)
    mesh = build("default", size=args.size, progress=sys.stderr.isatty())
    mesh.save(args.out)
    mesh = load(args.out)
    s = mesh.summary()
    print(f"built {args.out}: {s['faces']:,} triangles, {s['nodes']:,} nodes, {s['vertices']:,} vertices "
          f"in {s['build_seconds']:.2f} s")
    print(f"  base mesh {s['base_faces']:,} faces; {s['surface_group_ids']} surface group ids for "
          f"{s['surface_groups']} groups; positions {mesh.class_tally()}")
    print(f"  static bytes {s['static_bytes']:,} (Equation 1: {s['equation1_static_bytes']:,})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
