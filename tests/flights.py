"""Real refinement deltas for the op-stream tests: a flyover, encoded as the server encodes it."""

from __future__ import annotations

import caveclod
from caveclod import opstream
from caveclod.paths import pose
from caveclod.server.held import HeldBuffers


def flyover_streams(mesh, links: opstream.Links | None = None, cameras: int = 4, frames: int = 120,
                    step: float = 0.1):
    """Every delta of ``cameras`` cameras flying the flyover (camera c on path c, ``frames`` poses
    ``step`` seconds apart, 800x600), encoded against what the client holds, as the server does.

    Yields (camera state, material, the delta's surface, the (old_count, 3) buffer the client
    held before it, its OPS stream, its OPS_LINKED stream or None without ``links``).
    """
    lo, hi = mesh.bounds()
    ranks = None if links is None else opstream.child_ranks(links.targets)
    for c in range(cameras):
        cam = mesh.new_camera()
        plain = HeldBuffers(cam.n_materials)
        linked = None if links is None else HeldBuffers(cam.n_materials, (links.targets, ranks))
        client = {m: cam.index_buffer(m).copy() for m in range(cam.n_materials)}
        for m, buf in client.items():
            plain.replace(m, buf)
            if linked is not None:
                linked.replace(m, buf)
        for f in range(frames):
            p = pose("flyover", lo, hi, c, f * step)
            delta = cam.update(caveclod.View(eye=p.eye, target=p.target, up=p.up, width=800, height=600))
            for m, d in delta.surfaces.items():
                ops = plain.encode(m, d.count, d.slots, d.tris)
                linked_ops = None if linked is None else linked.encode(m, d.count, d.slots, d.tris)
                old = client[m]
                client[m] = cam.index_buffer(m).copy()
                yield cam, m, d, old, ops, linked_ops
