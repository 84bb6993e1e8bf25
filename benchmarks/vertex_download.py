"""The vertex download: bytes per vertex, packed (VERTEX_ENCODING_PACKED) against float32 and
meshoptimizer's vertex codec, and the error that quantizing adds on screen.

For the 1M-triangle default and rough terrains and the range scan, the
vertex buffer is packed with caveclod.vertexpack at several position_bits.
Reported per mesh and bits: bytes per vertex (float32 is 32), the time to
pack (once per mesh and bits, on the server) and to decode (numpy, the
Python client), the largest position error in world units, and what that
error is on screen: for every view of the cameras' path (the 4-camera
flyover over a whole lap, 1 view a second, for the terrains; the error
benchmark's 7 orbit views for the scan; 1280x720, 60 degrees), every vertex
in the view's frustum is displaced by its own decoded error and converted to
pixels at its own distance, as the screen-space test converts errors; the
largest over all views is the added error. Also: the fewest bits whose
added error stays at or under 0.1 px, and its bytes per vertex.

The reference: meshoptimizer's vertex codec (``encode_vertex_buffer``) on
the same vertices quantized as gltfpack quantizes by default (16-bit
positions padded to 8 bytes, 8-bit normals padded to 4, 16-bit UVs: 16
bytes a vertex), alone and deflated after it as glTF viewers serve it.

    .venv/bin/python benchmarks/vertex_download.py [--size 708] [--scan-size 400]

Writes benchmarks/results/vertex_download.json and vertex_download.png.
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import sys
import time
import zlib
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from service import RESULTS, mesh_path  # noqa: E402

BITS = (12, 14, 16, 18, 20, 22, 24)
TARGET_PX = 0.1


def built(name: str, size: int) -> Path:
    """benchmarks/results/NAME_SIZE.cvc, built when absent (the default terrain as service.py builds it)."""
    if name == "default":
        return mesh_path(size)
    path = RESULTS / f"{name}_{size}.cvc"
    if not path.exists():
        import caveclod
        print(f"building {name} --size {size} ...", file=sys.stderr)
        caveclod.build(name, size=size).save(path)
    return path


def views(mesh) -> list:
    """The views the error is measured in (see the module doc)."""
    import caveclod
    from caveclod.paths import flyover
    from error import views as orbit_views
    lo, hi = mesh.bounds()
    ext = hi - lo
    if ext[2] < max(ext[0], ext[1]) / 3:           # a terrain: the flyover, a whole lap
        return [caveclod.View.from_pose(flyover(lo, hi, c, float(t))) for c in range(4) for t in range(60)]
    return orbit_views(mesh, 1.0)


def screen_factors(view, positions: np.ndarray) -> np.ndarray:
    """(d,) kappa / distance of each vertex in ``view``'s frustum, 0 outside it."""
    eye, target, up = (np.asarray(v, np.float64) for v in (view.eye, view.target, view.up))
    forward = (target - eye) / np.linalg.norm(target - eye)
    right = np.cross(forward, up)
    right /= np.linalg.norm(right)
    upv = np.cross(right, forward)
    rel = positions - eye
    z = rel @ forward
    tan_y = math.tan(math.radians(view.fov_y) / 2)
    tan_x = tan_y * view.width / view.height
    inside = (z > 1e-9) & (np.abs(rel @ right) <= tan_x * z) & (np.abs(rel @ upv) <= tan_y * z)
    kappa = view.height / (2 * tan_y)
    dist = np.linalg.norm(rel, axis=1)
    return np.where(inside, kappa / np.maximum(dist, 1e-12), 0.0)


def meshopt_bytes(mesh) -> dict:
    """meshoptimizer's vertex codec on gltfpack-style 16-byte quantized vertices."""
    import meshoptimizer
    p = np.asarray(mesh.vertex_positions, np.float64)
    lo, ext = p.min(axis=0), float(np.ptp(p, axis=0).max()) or 1.0
    d = len(p)
    v = np.zeros((d, 8), np.uint16)
    v[:, :3] = np.rint((p - lo) / ext * 65535)
    n = np.clip(np.rint(np.asarray(mesh.vertex_normals) * 127), -127, 127).astype(np.int8)
    raw = v.view(np.uint8).reshape(d, 16)
    raw[:, 8:11] = n.view(np.uint8)
    uv = np.asarray(mesh.vertex_uvs, np.float64)
    ulo, uext = uv.min(axis=0), np.maximum(np.ptp(uv, axis=0), 1e-12)
    raw[:, 12:16] = np.rint((uv - ulo) / uext * 65535).astype(np.uint16).view(np.uint8).reshape(d, 4)
    t0 = time.perf_counter()
    encoded = meshoptimizer.encode_vertex_buffer(np.ascontiguousarray(raw), d, 16)
    seconds = time.perf_counter() - t0
    return {"bytes_per_vertex": round(len(encoded) / d, 3),
            "deflated_bytes_per_vertex": round(len(zlib.compress(encoded, 6)) / d, 3),
            "encode_s": round(seconds, 3), "position_bits": 16}


def measure(name: str, path: Path) -> dict:
    import caveclod
    from caveclod import vertexpack
    mesh = caveclod.load(path)
    p64 = np.asarray(mesh.vertex_positions, np.float64)
    d = len(p64)
    path_views = views(mesh)
    factors = [screen_factors(v, p64) for v in path_views]
    nearest = min(float(v.height / (2 * math.tan(math.radians(v.fov_y) / 2)) / f.max())
                  for v, f in zip(path_views, factors) if f.max() > 0)
    rows = []
    for bits in BITS:
        t0 = time.perf_counter()
        packed = vertexpack.pack(mesh.vertex_positions, mesh.vertex_normals, mesh.vertex_uvs, mesh.vertex_colors,
                                 bits)
        pack_s = time.perf_counter() - t0
        decode = []
        for _ in range(3):
            t0 = time.perf_counter()
            decoded = vertexpack.unpack(packed.packing, packed.data)
            decode.append(time.perf_counter() - t0)
        disp = np.linalg.norm(decoded["position"].astype(np.float64) - p64, axis=1)
        added = max(float((disp * f).max()) for f in factors)
        rows.append({"position_bits": bits, "bytes_per_vertex": round(len(packed.data) / d, 3),
                     "max_position_error": packed.max_position_error, "added_px": added,
                     "max_normal_degrees": round(packed.max_normal_degrees, 4), "pack_s": round(pack_s, 3),
                     "decode_s": round(statistics.median(decode), 4)})
        print(f"{name:8s} bits {bits:2d}: {rows[-1]['bytes_per_vertex']:5.2f} B/vertex, added {added:.4f} px, "
              f"pack {pack_s:.2f} s, decode {rows[-1]['decode_s']:.3f} s", file=sys.stderr)
    fit = next((r for r in rows if r["added_px"] <= TARGET_PX), None)
    return {"mesh": name, "path": path.name, "vertices": d, "faces": mesh.n_faces,
            "float32_bytes_per_vertex": 32 + 4 * (len(mesh.vertex_colors) > 0),
            "nearest_distance": nearest, "packed": rows,
            "fewest_bits_within_target": fit and fit["position_bits"],
            "bytes_per_vertex_within_target": fit and fit["bytes_per_vertex"],
            "default_bits": vertexpack.DEFAULT_POSITION_BITS,
            "meshoptimizer": meshopt_bytes(mesh)}


def plot(results: list, out: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, (a, b) = plt.subplots(1, 2, figsize=(11, 4))
    for r in results:
        bits = [x["position_bits"] for x in r["packed"]]
        a.plot(bits, [x["bytes_per_vertex"] for x in r["packed"]], marker="o", label=r["mesh"])
        b.semilogy(bits, [max(x["added_px"], 1e-6) for x in r["packed"]], marker="o", label=r["mesh"])
    a.axhline(8, ls=":", c="k", label="8 B (issue 18's goal)")
    a.set(xlabel="position bits", ylabel="bytes per vertex (float32: 32)", title="packed vertex download")
    b.axhline(TARGET_PX, ls=":", c="k", label=f"{TARGET_PX} px")
    b.set(xlabel="position bits", ylabel="added error, px (max over the path)", title="what quantizing adds")
    a.legend()
    b.legend()
    fig.tight_layout()
    fig.savefig(out, dpi=110)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--size", type=int, default=708, help="terrain size (708: about 1M triangles)")
    ap.add_argument("--scan-size", type=int, default=400, help="range scan size")
    args = ap.parse_args()
    results = [measure("default", built("default", args.size)), measure("rough", built("rough", args.size)),
               measure("scan", built("scan", args.scan_size))]
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / "vertex_download.json").write_text(json.dumps({"results": results}, indent=1))
    plot(results, RESULTS / "vertex_download.png")
    for r in results:
        print(f"{r['mesh']:8s} {r['vertices']:8d} vertices  nearest {r['nearest_distance']:.4g}  "
              f"<= {TARGET_PX} px from {r['fewest_bits_within_target']} bits: {r['bytes_per_vertex_within_target']} "
              f"B/vertex  (meshoptimizer 16-bit: {r['meshoptimizer']['bytes_per_vertex']}, deflated "
              f"{r['meshoptimizer']['deflated_bytes_per_vertex']})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
