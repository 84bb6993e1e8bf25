"""A large elevation model as a ``.npy`` file, for the builds and start-ups that need one.

Real 10,000 x 10,000 models (a 1 m LiDAR survey of 10 km, a 30 m model of
300 km) cannot be downloaded here, so this makes one with their traits: the
built-in rough terrain (fractal relief with the spectrum of real models,
ridges, flat lakes, no-data voids on steep ground and a jagged swath edge) at
half the side, doubled by linear interpolation (voids stay voids) and given
finer relief from a periodic fractal tile. Written as float32, as GeoTIFF
exports mostly are; no-data samples are NaN.

    .venv/bin/python benchmarks/large_dem.py --side 9999 --out /tmp/dem10k.npy    # about 30 s, 5 GB peak
    .venv/bin/python benchmarks/large_dem.py --side 19999 --out /tmp/dem20k.tif   # a GeoTIFF: read_window.py
    .venv/bin/caveclod build /tmp/dem10k.npy -o /tmp/dem.cvc            # refused: names --stride 2
    .venv/bin/caveclod build /tmp/dem10k.npy --stride 2 -o /tmp/dem.cvc  # 47M triangles, about 5 minutes
    .venv/bin/python benchmarks/service.py --skip capacity,parallel,shared --startup-mesh /tmp/dem.cvc \\
        --startup-repeats 3 --out /tmp/startup_dem.json
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from caveclod.builder.builtin import _fbm, rough_heights

FINE_TILE = 1024         # samples a side of the finer relief's periodic tile
FINE_RELIEF_M = 1.5      # its standard deviation, metres


def large_dem(side: int, seed: int = 23) -> np.ndarray:
    """(side, side) float32 heights, side odd (the doubling keeps every coarse sample), NaN voids."""
    if side < 5 or side % 2 == 0:
        raise ValueError(f"--side must be odd and at least 5, got {side}")
    coarse = rough_heights((side + 1) // 2 - 1, seed)            # (n, n), n = (side + 1) / 2
    out = np.empty((side, side), np.float32)
    out[::2, ::2] = coarse
    out[1::2, ::2] = 0.5 * (coarse[:-1] + coarse[1:])
    out[::2, 1::2] = 0.5 * (coarse[:, :-1] + coarse[:, 1:])
    out[1::2, 1::2] = 0.25 * (coarse[:-1, :-1] + coarse[1:, :-1] + coarse[:-1, 1:] + coarse[1:, 1:])
    del coarse
    tile = _fbm(FINE_TILE, np.random.default_rng(seed + 1)).astype(np.float32)
    tile = (tile - tile.mean()) / tile.std() * FINE_RELIEF_M
    for r in range(0, side, FINE_TILE):
        for c in range(0, side, FINE_TILE):
            block = out[r:r + FINE_TILE, c:c + FINE_TILE]
            block += tile[:block.shape[0], :block.shape[1]]
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--side", type=int, default=9999, help="samples a side, odd (9999: 199,920,008 triangles "
                                                          "less the voids')")
    ap.add_argument("--seed", type=int, default=23)
    ap.add_argument("--out", required=True, help="the .npy to write, or a .tif (a BigTIFF in strips of "
                                                 "--strip-rows rows, no-data -9999 in its GDAL_NODATA tag)")
    ap.add_argument("--strip-rows", type=int, default=16, help="rows a strip of a .tif (default 16)")
    args = ap.parse_args()
    t0 = time.perf_counter()
    heights = large_dem(args.side, args.seed)
    if args.out.lower().endswith((".tif", ".tiff")):
        import tifffile
        tifffile.imwrite(args.out, np.nan_to_num(heights, nan=-9999.0), bigtiff=True, rowsperstrip=args.strip_rows,
                         extratags=[(42113, 2, 0, "-9999", True)])
    else:
        np.save(args.out, heights)
    print(f"{args.out}: {heights.shape[0]:,} x {heights.shape[1]:,} samples, "
          f"{np.isnan(heights).mean():.1%} no-data, {time.perf_counter() - t0:.1f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
