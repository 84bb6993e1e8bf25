"""The frame encodings' op streams on a flyover's real deltas, offline: bytes a write and what they cost.

    python benchmarks/opstream.py [--size 708] [--cameras 32] [--seconds 15] [--repeats 3]

``--cameras`` cameras (camera k flies path camera k, as ``caveclod loadtest``'s
sessions do) fly the flyover at 30 Hz on the 1M-triangle default terrain,
1280x720, 60°, 1 px. Every delta after the first second (refining up from the
base mesh) is encoded as FRAME_ENCODING_OPS and as OPS_LINKED against what
the client holds, as the server does (``HeldBuffers``), and both streams are
decoded and checked against the camera's buffer. Reported: bytes a write of
each encoding (RAW's slot and triangle arrays: 16), OPS_LINKED's bytes by
part (in-place writes' headers, appended writes' kinds, each kind's
payloads) and its kinds' shares; the encoders' microseconds a stream (as the
server calls them) and the decoders' (Python/numpy as thin clients run them,
and compiled as the load generator does), medians over ``--repeats`` timings
of the first 3,000 streams. Writes ``benchmarks/results/opstream.json`` and
``opstream.png``.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from service import RESULTS, mesh_path  # noqa: E402

TIMED = 3000                      # streams whose decoding is timed (their old buffers are kept)
KIND_NAMES = {0: "NEW", 1: "COPY", 2: "CORNER", 3: "CORNER", 4: "CORNER", 5: "SPLIT", 6: "SPLIT", 7: "SPLIT",
              8: "MERGE", 9: "MERGE", 10: "MERGE", 11: "ADJ", 12: "ADJ_T", 13: "ADJ_T"}


def varint_bytes(value: int) -> int:
    n = 1
    while value >= 0x80:
        value >>= 7
        n += 1
    return n


def linked_parts(ops: bytes, old_count: int, count: int, out: dict, kinds_seen: dict) -> None:
    """Add an OPS_LINKED stream's bytes by part (the proto's layout) to ``out``, its kinds to ``kinds_seen``."""
    from caveclod import opstream
    values = [int(v) for v in opstream.read_varints(ops)]
    n = values[0]
    appended = max(count - old_count, 0)
    in_place = n - appended
    packs = -(-appended // opstream.APPENDED_PER_VARINT)
    out["count"] = out.get("count", 0) + varint_bytes(n)
    out["in-place headers"] = out.get("in-place headers", 0) + sum(map(varint_bytes, values[1:1 + in_place]))
    out["appended kinds"] = out.get("appended kinds", 0) + packs
    kinds = [h & 15 for h in values[1:1 + in_place]]
    base = len(opstream.APPENDED_KINDS)
    for pack in values[1 + in_place:1 + in_place + packs]:
        for _ in range(min(opstream.APPENDED_PER_VARINT, n - len(kinds))):
            pack, code = divmod(pack, base)
            kinds.append(opstream.APPENDED_KINDS[code])
    p = 1 + in_place + packs
    for kind in kinds:
        width = opstream.LINKED_PAYLOAD_VARINTS[kind]
        name = KIND_NAMES[kind]
        out[name] = out.get(name, 0) + sum(map(varint_bytes, values[p:p + width]))
        kinds_seen[name] = kinds_seen.get(name, 0) + 1
        p += width


def fly(mesh_file: Path, cameras: int, seconds: float) -> dict:
    """Encode every delta of the flight both ways; the streams to time and the byte tallies."""
    import caveclod
    from caveclod import opstream
    from caveclod.paths import pose
    from caveclod.refine.morphtargets import morph_targets
    from caveclod.server.held import HeldBuffers

    mesh = caveclod.load(mesh_file)
    lo, hi = mesh.bounds()
    links = opstream.Links(morph_targets(mesh))
    ranks = opstream.child_ranks(links.targets)
    writes = plain_bytes = linked_bytes = streams = 0
    parts, kinds, encode_us = {}, {}, {"ops": [], "linked": []}
    timed = []                     # (ops, linked ops, old, count) of the first TIMED streams
    for k in range(cameras):
        cam = mesh.new_camera()
        plain, linked = HeldBuffers(cam.n_materials), HeldBuffers(cam.n_materials, (links.targets, ranks))
        client = {m: cam.index_buffer(m).copy() for m in range(cam.n_materials)}
        for m, buf in client.items():
            plain.replace(m, buf)
            linked.replace(m, buf)
        for f in range(int(seconds * 30)):
            p = pose("flyover", lo, hi, k, f / 30)
            delta = cam.update(caveclod.View(eye=p.eye, target=p.target, up=p.up, width=1280, height=720))
            for m, d in delta.surfaces.items():
                t0 = time.perf_counter()
                ops = plain.encode(m, d.count, d.slots, d.tris)
                t1 = time.perf_counter()
                lops = linked.encode(m, d.count, d.slots, d.tris)
                t2 = time.perf_counter()
                old = client[m]
                client[m] = cam.index_buffer(m).copy()
                slots, tris = opstream.decode_linked(lops, old, d.count, links)
                new = np.zeros((d.count, 3), np.uint32)
                new[:min(len(old), d.count)] = old[:d.count]
                new[slots] = tris
                plain_slots, plain_tris = opstream.decode(ops, old, d.count, mesh.n_vertices)
                if not (np.array_equal(new, client[m]) and np.array_equal(plain_slots, slots)
                        and np.array_equal(plain_tris, tris)):
                    raise AssertionError(f"camera {k} frame {f}: a stream does not decode to the camera's buffer")
                if f < 30 or not len(d.slots):
                    continue
                streams += 1
                writes += len(d.slots)
                plain_bytes += len(ops)
                linked_bytes += len(lops)
                encode_us["ops"].append((t1 - t0) * 1e6)
                encode_us["linked"].append((t2 - t1) * 1e6)
                linked_parts(lops, len(old), d.count, parts, kinds)
                if len(timed) < TIMED:
                    timed.append((ops, lops, old, d.count))
    return {"mesh": mesh, "links": links, "timed": timed, "streams": streams, "writes": writes,
            "plain_bytes": plain_bytes, "linked_bytes": linked_bytes, "parts": parts, "kinds": kinds,
            "encode_us": encode_us}


def decode_us(timed: list, links, n_vertices: int, repeats: int) -> dict:
    """Microseconds a stream of each decoder over the timed streams (median of ``repeats`` passes)."""
    from caveclod import opstream
    passes = {"ops, python/numpy": lambda: [opstream.decode(o, old, c, n_vertices) for o, _, old, c in timed],
              "linked, python": lambda: [opstream.decode_linked(lo, old, c, links) for _, lo, old, c in timed]}
    out = {}
    for compiled in (False, True):
        with opstream.compiled_decoding(compiled):
            for name, run in passes.items():
                if compiled:
                    name = name.split(",")[0] + ", compiled"
                times = []
                for _ in range(repeats):
                    t = time.perf_counter()
                    run()
                    times.append((time.perf_counter() - t) / len(timed) * 1e6)
                out[name] = round(statistics.median(times), 2)
    return out


def plot(report: dict, path: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, (ax, bx) = plt.subplots(1, 2, figsize=(12, 4))
    parts = report["linked_bytes_per_write_by_part"]
    bottom = 0.0
    for k, (name, value) in enumerate(parts.items()):
        ax.bar(["OPS_LINKED"], [value], bottom=bottom, color=f"C{k}", label=name)
        bottom += value
    ax.bar(["OPS"], [report["ops_bytes_per_write"]], color="grey")
    ax.bar(["RAW"], [16.0], color="lightgrey")
    ax.set_ylabel("bytes a write (changed triangle)")
    ax.set_title("op stream bytes a write, flyover deltas", fontsize=9)
    ax.legend(fontsize=7)
    names = list(report["encode_us"]) + list(report["decode_us"])
    values = list(report["encode_us"].values()) + list(report["decode_us"].values())
    bx.barh(names, values, color=[f"C{k % 10}" for k in range(len(names))])
    bx.set_xlabel("microseconds a stream (median)")
    bx.set_title("encoders (server) and decoders (clients)", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--size", type=int, default=708, help="the default terrain's --size (708: 1M triangles)")
    ap.add_argument("--cameras", type=int, default=32)
    ap.add_argument("--seconds", type=float, default=15.0, help="seconds of flight per camera at 30 Hz")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--out", default=str(RESULTS / "opstream.json"))
    args = ap.parse_args()
    flight = fly(mesh_path(args.size), args.cameras, args.seconds)
    w = flight["writes"]
    report = {
        "mesh": f"default --size {args.size}", "cameras": args.cameras, "seconds": args.seconds,
        "streams": flight["streams"], "writes": w,
        "writes_per_stream": round(w / flight["streams"], 1),
        "ops_bytes_per_write": round(flight["plain_bytes"] / w, 3),
        "linked_bytes_per_write": round(flight["linked_bytes"] / w, 3),
        "linked_bytes_per_write_by_part": {k: round(v / w, 3) for k, v in sorted(flight["parts"].items(),
                                                                                 key=lambda kv: -kv[1])},
        "linked_kind_shares": {k: round(v / w, 3) for k, v in sorted(flight["kinds"].items(), key=lambda kv: -kv[1])},
        "encode_us": {f"{k} encoder": round(statistics.median(v), 2) for k, v in flight["encode_us"].items()},
        "decode_us": decode_us(flight["timed"], flight["links"], flight["mesh"].n_vertices, args.repeats),
    }
    print(json.dumps(report, indent=1))
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(report, indent=1) + "\n")
    plot(report, out.with_suffix(".png"))
    return 0


if __name__ == "__main__":
    sys.exit(main())
