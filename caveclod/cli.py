"""The ``caveclod`` command line.

    caveclod build INPUT -o OUT.cvc [--json] [--size N] [--cell-size X] ...
    caveclod inspect OUT.cvc [--json] [--verify]

Errors print one line on stderr and exit with status 2; never a traceback.
"""

from __future__ import annotations

import argparse
import json
import sys

from .errors import CaveclodError

EXIT_USAGE = 2


def main(argv: list[str] | None = None) -> int:
    parser = _parser()
    args = parser.parse_args(argv)
    try:
        return args.run(args)
    except CaveclodError as exc:
        print(f"caveclod: error: {exc}", file=sys.stderr)
        return EXIT_USAGE
    except ModuleNotFoundError as exc:
        print(f"caveclod: error: '{args.command}' needs the Python package {exc.name!r}, which is not installed; "
              "install the extras it needs, e.g. pip install 'caveclod[all]'", file=sys.stderr)
        return EXIT_USAGE
    except MemoryError:
        print("caveclod: error: out of memory; build a smaller input or use a machine with more memory", file=sys.stderr)
        return EXIT_USAGE
    except KeyboardInterrupt:
        print("caveclod: interrupted", file=sys.stderr)
        return 130


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="caveclod", description="View-dependent continuous LOD for many cameras.")
    sub = p.add_subparsers(dest="command", required=True)

    b = sub.add_parser("build", help="build a static CAVECLOD mesh (.cvc) from a mesh, a heightfield or a built-in")
    b.add_argument("input", help="mesh file (OBJ, PLY, GLB/glTF, STL, OFF), heightfield (.npy, 16-bit .png/.tif) or a "
                                 "built-in: 'default' (smooth terrain), 'rough' (rough terrain with no-data holes), "
                                 "'scan' (a range scan)")
    b.add_argument("-o", "--output", required=True, help="the .cvc file to write")
    b.add_argument("--json", action="store_true", help="print the build report as one JSON object on stdout")
    b.add_argument("--size", type=int, default=256, help="cells per side of a built-in (default 256: 131,072 "
                                                         "triangles of the default terrain)")
    b.add_argument("--seed", type=int, help="seed of a built-in")
    b.add_argument("--cell-size", type=float, default=1.0, help="heightfield grid spacing")
    b.add_argument("--z-scale", type=float, default=1.0, help="heightfield height scale")
    b.add_argument("--materials", help="heightfield material map (.npy, one integer class per cell)")
    b.add_argument("--nodata", type=float, help="heightfield value marking missing samples, which become holes "
                                                "(NaN, a GeoTIFF's GDAL_NODATA and -32768 in 16-bit signed grids always do)")
    b.add_argument("--crease-angle", type=float, help="degrees; edges sharper than this become normal seams where the "
                                                     "input has no normals (default: 30 for meshes, smooth normals "
                                                     "for heightfields)")
    b.add_argument("--weld", type=float, help="merge positions closer than about this distance "
                                              "(default: only bitwise-equal positions are one)")
    b.add_argument("--quiet", action="store_true", help="no progress on stderr")
    b.set_defaults(run=_build)

    i = sub.add_parser("inspect", help="print the counts of a .cvc file")
    i.add_argument("path")
    i.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    i.add_argument("--verify", action="store_true", help="re-hash the whole file and check it is intact")
    i.set_defaults(run=_inspect)
    return p


def _build(args) -> int:
    from .api import build
    mesh = build(args.input, cell_size=args.cell_size, z_scale=args.z_scale, materials=args.materials,
                 crease_angle=args.crease_angle, size=args.size, seed=args.seed, nodata=args.nodata, weld=args.weld,
                 progress=not args.quiet)
    try:
        mesh.save(args.output)
    except OSError as exc:
        raise CaveclodError(f"cannot write {args.output}: {exc.strerror}; check the directory exists and is writable") from None
    report = mesh.summary()
    report["output"] = args.output
    _print(report, args.json)
    return 0


def _inspect(args) -> int:
    from .api import load
    mesh = load(args.path)
    if args.verify:
        mesh.verify()
    report = mesh.summary()
    report["classes"] = mesh.class_tally()
    report["path"] = args.path
    _print(report, args.json)
    return 0


def _print(report: dict, as_json: bool) -> None:
    if as_json:
        print(json.dumps(report))
        return
    width = max(len(k) for k in report)
    for key, value in report.items():
        print(f"{key:<{width}}  {value}")


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
