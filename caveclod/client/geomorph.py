"""Geomorphs for a thin client: splits and collapses drawn as smooth changes of shape.

One :class:`Geomorphs` per camera. It is fed the ``SurfaceDelta`` writes the
client library applied (the *logical* buffers, equal to the server's
mirror) and tells a renderer what to draw instead: *display* index buffers
and, for the vertices on their way somewhere, where they are drawn at a
given time. Hoppe's geomorphs, per camera and incremental:

* What morphs is a **point** (the vertices with one set of coordinates: a
  texture or normal seam's two or more vertex-buffer entries), so a seam
  never opens.
* A point that **appears** (no triangle of the camera used it; now one
  does) starts where the surface already is, at its *anchor* (the first
  point along its morph targets that the camera drew before the frame:
  the point it split out of, or that one's own target when both are new),
  and moves home over ``duration``. At the frame's instant the new
  triangles lie in the surface drawn until then (a vsplit geomorph).
* A point that **goes** (the last triangle using it was rewritten or
  removed) moves from where it is onto its anchor (the first point along
  its targets that the camera still draws) over ``duration``, while the
  display keeps its old triangles: a slot whose new triangle is the old one
  with the going vertices replaced by their anchors' (a collapse's
  re-pointed corner) keeps showing the old triangle (*held*); any other old
  triangle with a going vertex (the collapse's two vanishing faces) is drawn
  after the buffer's triangles (*kept*). When the point arrives, it is
  replaced by its anchor in those triangles: a held triangle that then
  equals its slot's logical one is released, a kept one that became
  degenerate is dropped.
* An anchor is followed where it is drawn *now*, so cascades stay whole: a
  point shrinking onto one that starts shrinking too follows it, and one
  that arrives hands its followers on to its own anchor. A going point that
  comes back moves home from where it is.

Where a frame only splits, the surface drawn at its instant is the surface
drawn just before (tests/test_geomorph.py checks every frame of zooms);
where it also collapses, a triangle changed two ways in one update has no
old form to morph from and shows at once (rare: the tests bound the jumps
of flights against those without morphs). Once the morphs are over the
display is exactly the mesh the server sent. A keyframe is not
morphed (the camera starts over). Numpy only (no GL), so renderers and the
benchmark share it; a renderer gives each camera its own position buffer
(:meth:`Geomorphs.moving` rows) and draws :meth:`Geomorphs.display`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..frames import Surface

MIN_SPAN = 1e-3
"""Seconds the shortest morph takes with a speed (a slide of a fraction of a pixel)."""


@dataclass
class Changes:
    """What a renderer must change to draw the display.

    Attributes:
        writes: ``(material, count, slots (k,), tris (k, 3) uint32)`` display-buffer
            writes, as a SurfaceDelta's (slots ascending, below ``count``).
        reset: the camera started over: empty its buffers first.
    """

    writes: list = field(default_factory=list)
    reset: bool = False


@dataclass
class _Morph:
    """One point on its way: from ``start`` (a point, followed, or fixed coordinates) to ``end``."""

    t0: float
    start: int | None             # anchor point it grows out of (appear), or None: from `fixed`
    fixed: np.ndarray | None      # (3,) where it started (going, or coming back)
    end: int | None               # anchor point it shrinks onto (going), or None: home
    span: float                   # seconds it takes


class Geomorphs:
    """The display of one camera's index buffers, splits and collapses morphed.

    Args:
        positions: (d, 3) float32 the vertex buffer's positions.
        targets: (d,) morph targets (:attr:`caveclod.client.VertexBuffer.morph_targets`).
        materials: index buffers per camera.
        duration: seconds a morph takes (> 0); with ``speed``, the most it takes.
        points: :func:`points_of` of the buffer (computed when not given;
            share it between the cameras of one vertex buffer).
        speed: None, or pixels a second: each morph then takes as long as
            its path on screen needs at that speed (at most ``duration``),
            measured from where :meth:`look_from` last put the camera, so
            that a long slide moves no faster than a short one.
    """

    def __init__(self, positions: np.ndarray, targets: np.ndarray, materials: int, duration: float,
                 points: tuple | None = None, speed: float | None = None):
        if not duration > 0:
            raise ValueError(f"a geomorph takes a positive duration, got {duration!r}")
        if speed is not None and not speed > 0:
            raise ValueError(f"a geomorph's speed must be positive pixels a second, got {speed!r}")
        self.speed = None if speed is None else float(speed)
        self._eye, self._kappa = None, 0.0               # where the camera is (look_from)
        self.positions = np.asarray(positions, np.float32)
        self.targets = np.asarray(targets, np.int64).reshape(-1)
        d = len(self.positions)
        if self.targets.shape != (d,) or (d and (self.targets.min() < 0 or self.targets.max() >= d)):
            raise ValueError(f"morph targets must be ({d},) indices into the vertex buffer")
        self.materials, self.duration = int(materials), float(duration)
        self.point, self.point_target, self._start, self._members = points or points_of(self.positions, self.targets)
        self.point_refs = np.zeros(len(self.point_target), np.int32)  # logical triangle corners at each point
        self.rows = [np.zeros((0, 3), np.int64) for _ in range(materials)]    # the logical buffers
        self._unposed = False                               # showing a keyframe that answered no pose
        self.held = [dict() for _ in range(materials)]      # slot -> (3,) display triangle
        self.kept = [[] for _ in range(materials)]          # display triangles after the buffer
        self.active: dict[int, _Morph] = {}                 # point -> its morph
        self._shown_kept = [0] * materials                  # kept triangles the renderer holds
        self._moved: set[int] = set()                       # points whose drawn position changed since `moving`
        self.snaps = 0                                      # display triangles that ended unlike the logical

    # -- what is drawn ---------------------------------------------------------------
    def look_from(self, eye, kappa: float) -> None:
        """Where the camera is for the morphs the next frames begin (with a ``speed``): ``eye`` (3,)
        and ``kappa``, pixels a unit spans at distance 1 (:func:`pixels_per_unit`)."""
        self._eye = tuple(float(x) for x in np.asarray(eye, np.float64).reshape(3))
        self._kappa = float(kappa)

    def display(self, material: int) -> np.ndarray:
        """(count + kept, 3) uint32: the display buffer of ``material``, as the renderer holds it."""
        rows = self.rows[material].astype(np.uint32)
        for slot, tri in self.held[material].items():
            rows[slot] = tri
        kept = np.array(self.kept[material], np.uint32).reshape(-1, 3)
        return np.concatenate([rows, kept]) if len(kept) else rows

    def point_at(self, p: int, now: float, _depth: int = 0) -> np.ndarray:
        """(3,) float64 where point ``p`` is drawn at ``now``."""
        m = self.active.get(p)
        own = self.positions[self._members[self._start[p]]].astype(np.float64)
        if m is None or _depth > 64:
            return own
        u = min(max((now - m.t0) / m.span, 0.0), 1.0)
        a = m.fixed if m.start is None else self.point_at(m.start, now, _depth + 1)
        b = own if m.end is None else self.point_at(m.end, now, _depth + 1)
        return a + (b - a) * u

    def points_at(self, points, now: float) -> np.ndarray:
        """(k, 3) float64 where ``points`` are drawn at ``now``: :meth:`point_at` for many, evaluated
        level by level (an anchor before its followers) in numpy."""
        points = np.asarray(points, np.int64)
        own = self.positions[self._members[self._start[points]]].astype(np.float64) if len(points) else \
            np.zeros((0, 3))
        if not self.active:
            return own
        act = np.fromiter(self.active, np.int64, len(self.active))
        morphs = [self.active[p] for p in act.tolist()]
        t0 = np.array([m.t0 for m in morphs])
        span = np.array([m.span for m in morphs])
        start = np.array([-1 if m.start is None else m.start for m in morphs], np.int64)
        end = np.array([-1 if m.end is None else m.end for m in morphs], np.int64)
        fixed = np.array([m.fixed if m.fixed is not None else (0.0, 0.0, 0.0) for m in morphs], np.float64)
        u = np.clip((now - t0) / span, 0.0, 1.0)[:, None]
        home = self.positions[self._members[self._start[act]]].astype(np.float64)
        slot = {p: i for i, p in enumerate(act.tolist())}
        si = np.array([slot.get(int(x), -1) for x in start], np.int64)      # an active anchor: its row
        ei = np.array([slot.get(int(x), -1) for x in end], np.int64)
        a = np.where((start < 0)[:, None], fixed, self.positions[self._members[self._start[np.maximum(start, 0)]]])
        b = np.where((end < 0)[:, None], home, self.positions[self._members[self._start[np.maximum(end, 0)]]])
        where = a + (b - a) * u
        done = (si < 0) & (ei < 0)
        for _ in range(64):                  # anchors of anchors: as deep as the cascades go
            if done.all():
                break
            ready = ~done & ((si < 0) | done[np.maximum(si, 0)]) & ((ei < 0) | done[np.maximum(ei, 0)])
            if not ready.any():
                break                        # a cycle (damage): those points stay where they are now
            r = np.flatnonzero(ready)
            ar = np.where((si[r] < 0)[:, None], a[r], where[np.maximum(si[r], 0)])
            br = np.where((ei[r] < 0)[:, None], b[r], where[np.maximum(ei[r], 0)])
            where[r] = ar + (br - ar) * u[r]
            done[r] = True
        rows = np.array([slot.get(int(p), -1) for p in points], np.int64)
        return np.where((rows < 0)[:, None], own, where[np.maximum(rows, 0)]) if len(points) else own

    def drawn_positions(self, now: float) -> np.ndarray:
        """(d, 3) float64 every vertex where it is drawn at ``now`` (for measuring; renderers use :meth:`moving`)."""
        out = self.positions.astype(np.float64)
        if self.active:
            pts = np.fromiter(self.active, np.int64, len(self.active))
            counts = self._start[pts + 1] - self._start[pts]
            out[self._vertices(pts)] = np.repeat(self.points_at(pts, now), counts, axis=0)
        return out

    def moving(self, now: float) -> tuple[np.ndarray, np.ndarray]:
        """``(vertices (k,), positions (k, 3) float32)``: the rows of the camera's position buffer
        that differ from the last call's (the moving points, and those that just arrived)."""
        pts = set(self.active) | self._moved
        self._moved = set(self.active)
        if not pts:
            return np.zeros(0, np.int64), np.zeros((0, 3), np.float32)
        pts = np.array(sorted(pts), np.int64)
        counts = self._start[pts + 1] - self._start[pts]
        return self._vertices(pts), np.repeat(self.points_at(pts, now), counts, axis=0).astype(np.float32)

    # -- frames in -------------------------------------------------------------------
    def apply(self, surfaces, keyframe: bool, now: float, posed: bool = True) -> Changes:
        """Take one frame's writes of this camera (``caveclod.wire.Surface``-like: material, count,
        slots (k,), tris (k, 3)), after emptying its buffers when ``keyframe``: the display
        :class:`Changes`. Morphs over by ``now`` end first. A material's writes may come in pieces
        (a frame cut across parts): they are joined first.

        ``posed``: the frame answers a pose (its ``pose_seq`` is not 0). A session's first
        keyframe goes out before the camera's first pose, so it holds the base mesh; the frame
        answering that pose holds the whole first refinement, which morphed out of the base mesh
        over the morph time (every render's first half second drawn from the base mesh). A frame
        after a keyframe that answered no pose is shown as it is, as a keyframe is."""
        surfaces = joined(surfaces)
        out = self.tick(now)
        if keyframe or self._unposed:
            if not keyframe:
                surfaces = self._whole(surfaces)
            self._unposed = not posed
            return self._restart(surfaces, out)
        before = self.point_refs.copy()
        touched, lost_display, new_at = [], [], {}
        for s in surfaces:
            m, count = s.material, int(s.count)
            slots = np.asarray(s.slots, np.int64)
            tris = np.asarray(s.tris, np.int64).reshape(-1, 3)
            rows = self.rows[m]
            lost = np.r_[slots[slots < len(rows)], np.arange(count, len(rows))]
            for slot in lost.tolist():           # what the screen showed there
                shown = self.held[m].pop(slot, None)
                lost_display.append((m, rows[slot] if shown is None else np.asarray(shown, np.int64)))
            for arr, sign in ((rows[lost].reshape(-1), -1), (tris.reshape(-1), 1)):
                np.add.at(self.point_refs, self.point[arr], sign)
                touched.append(self.point[arr])
            grown = np.zeros((count, 3), np.int64)
            keep = min(count, len(rows))
            grown[:keep] = rows[:keep]
            grown[slots] = tris
            self.rows[m] = grown
            new_at[m] = {_key(t): int(sl) for sl, t in zip(slots.tolist(), tris.tolist())}
        changed = np.unique(np.concatenate(touched)) if touched else np.zeros(0, np.int64)
        appear = changed[(before[changed] == 0) & (self.point_refs[changed] > 0)].tolist()
        going = changed[(before[changed] > 0) & (self.point_refs[changed] == 0)].tolist()
        for p in appear:
            self._appear(p, before, now)
        for p in going:
            self._go(p, now)
        self._replace(lost_display, new_at)
        self._emit(out, surfaces)
        return out

    def tick(self, now: float) -> Changes:
        """End the morphs that are over at ``now`` (call before drawing); the display :class:`Changes`."""
        out = Changes()
        # `now` may be t0 + span, rounded
        done = sorted((m.t0, p) for p, m in self.active.items() if now - m.t0 >= m.span * (1.0 - 1e-9))
        if not done:
            return out
        arrived = {}                         # going point -> the anchor that takes its place
        for _, p in done:
            m = self.active.pop(p)
            self._moved.add(p)
            if m.end is not None:
                arrived[p] = m.end
        touched = set()
        if arrived:
            self._hand_on(arrived, touched)
        self._emit(out, [], touched)
        return out

    # -- internals ---------------------------------------------------------------------
    def _whole(self, surfaces) -> list:
        """Every material's buffer once ``surfaces``' writes are applied to it, as a keyframe's."""
        rows = list(self.rows)
        for s in surfaces:
            m, count = s.material, int(s.count)
            grown = np.zeros((count, 3), np.int64)
            keep = min(count, len(rows[m]))
            grown[:keep] = rows[m][:keep]
            grown[np.asarray(s.slots, np.int64)] = np.asarray(s.tris, np.int64).reshape(-1, 3)
            rows[m] = grown
        return [Surface(m, len(r), np.arange(len(r), dtype=np.uint32), r.astype(np.uint32), None)
                for m, r in enumerate(rows)]

    def _restart(self, surfaces, out: Changes) -> Changes:
        """A keyframe: the camera starts over, nothing morphs."""
        self._moved |= set(self.active)
        self.active.clear()
        self.point_refs[:] = 0
        for m in range(self.materials):
            self.rows[m] = np.zeros((0, 3), np.int64)
            self.held[m].clear()
            self.kept[m] = []
            self._shown_kept[m] = 0
        out.reset = True
        out.writes = []
        for s in surfaces:
            tris = np.asarray(s.tris, np.int64).reshape(-1, 3)
            rows = np.zeros((int(s.count), 3), np.int64)
            rows[np.asarray(s.slots, np.int64)] = tris
            self.rows[s.material] = rows
            np.add.at(self.point_refs, self.point[tris.reshape(-1)], 1)
            out.writes.append((s.material, int(s.count), np.asarray(s.slots, np.int64), tris.astype(np.uint32)))
        return out

    def _anchor(self, p: int, refs: np.ndarray) -> int:
        """The first point along ``p``'s targets that ``refs`` counts as drawn, or -1 (none)."""
        t = p
        for _ in range(256):                 # a hierarchy is at most this deep; a cycle is damage
            nxt = int(self.point_target[t])
            if nxt == t:
                return -1
            t = nxt
            if refs[t] > 0:
                return t
        return -1

    def _appear(self, p: int, before: np.ndarray, now: float) -> None:
        back = self.active.get(p)
        if back is not None and back.end is not None:
            # A going point comes back: home from where it is; what held it on screen goes.
            here = self.point_at(p, now)
            self.active[p] = _Morph(now, None, here, None, self._span(here, self._home(p)))
            self._drop_triangles_of(p)
            return
        anchor = self._anchor(p, before)
        if anchor >= 0:
            self.active[p] = _Morph(now, anchor, None, None, self._span(self.point_at(anchor, now), self._home(p)))
        self._moved.add(p)

    def _go(self, p: int, now: float) -> None:
        anchor = self._anchor(p, self.point_refs)
        if anchor < 0:
            self.active.pop(p, None)         # nothing to shrink onto: it goes at once
            self._moved.add(p)
            return
        here = self.point_at(p, now)
        self.active[p] = _Morph(now, None, here, anchor, self._span(here, self.point_at(anchor, now)))

    def _home(self, p: int) -> np.ndarray:
        """(3,) float64 point ``p``'s own position."""
        return self.positions[self._members[self._start[p]]].astype(np.float64)

    def _span(self, a: np.ndarray, b: np.ndarray) -> float:
        """Seconds a morph from ``a`` to ``b`` (3,) takes: ``duration``, or with a speed its length on
        screen (at the nearer end's distance) over the speed, at most ``duration``."""
        if self.speed is None or self._eye is None:
            return self.duration
        pixels = _apart(a, b) * self._kappa / max(min(_apart(a, self._eye), _apart(b, self._eye)), 1e-9)
        return min(self.duration, max(pixels / self.speed, MIN_SPAN))

    def _anchor_vertex(self, v: int, end: int) -> int:
        """The vertex that takes vertex ``v``'s place when its point arrives on point ``end``: along
        ``v``'s targets, the first on ``end`` (the same surface group's, where the hierarchy has one)."""
        t = v
        for _ in range(256):
            if self.point[t] == end:
                return t
            nxt = int(self.targets[t])
            if nxt == t:
                break
            t = nxt
        return int(self._members[self._start[end]])

    def _closure(self, tri) -> tuple:
        """``tri`` with every going vertex replaced by its anchor's, until none is going."""
        out = []
        for v in tri:
            v = int(v)
            for _ in range(64):
                m = self.active.get(int(self.point[v]))
                if m is None or m.end is None:
                    break
                v = self._anchor_vertex(v, m.end)
            out.append(v)
        return tuple(out)

    def _replace(self, lost_display: list, new_at: dict) -> None:
        """Old display triangles with a going vertex stay on screen: held at the slot whose new
        triangle they morph into, or kept."""
        for m, tri in lost_display:
            if not self._going(tri):
                continue
            moved = self._closure(tri)
            slot = new_at.get(m, {}).get(_key(moved)) if len(set(moved)) == 3 else None
            if slot is not None and slot not in self.held[m]:
                self.held[m][slot] = np.asarray(tri, np.int64)
            else:
                self.kept[m].append(np.asarray(tri, np.int64))

    def _hand_on(self, arrived: dict, touched: set) -> None:
        """Going points arrived on their anchors (``{point: anchor}``): their followers follow the
        anchors, their triangles use the anchors' vertices, and a held or kept triangle with nothing
        left on its way is released (held) or dropped (kept)."""
        def final(p):                        # an anchor that arrived too hands on to its own
            for _ in range(64):
                if p not in arrived:
                    return p
                p = arrived[p]
            return p
        arrived = {p: final(a) for p, a in arrived.items()}
        for m in self.active.values():
            if m.start in arrived:
                m.start = arrived[m.start]
            if m.end in arrived:
                m.end = arrived[m.end]
        swap = {int(v): self._anchor_vertex(int(v), a) for p, a in arrived.items() for v in self._vertices([p])}
        going = self._going_points()
        for mat in range(self.materials):
            for slot, tri in list(self.held[mat].items()):
                if not any(int(v) in swap for v in tri):
                    continue
                new = np.array([swap.get(int(v), int(v)) for v in tri], np.int64)
                if going[self.point[new]].any():
                    self.held[mat][slot] = new
                else:                        # nothing left to morph: the slot shows what the server sent
                    del self.held[mat][slot]
                    self.snaps += not np.array_equal(new, self.rows[mat][slot])
                touched.add((mat, slot))
            if self.kept[mat]:
                kept = np.array(self.kept[mat], np.int64).reshape(-1, 3)
                flat = kept.reshape(-1)
                hit = np.isin(flat, np.fromiter(swap, np.int64, len(swap)))
                if hit.any():
                    flat = flat.copy()
                    flat[hit] = [swap[int(v)] for v in flat[hit]]
                    kept = flat.reshape(-1, 3)
                    live = going[self.point[kept]].any(axis=1)
                    whole = (kept[:, 0] != kept[:, 1]) & (kept[:, 1] != kept[:, 2]) & (kept[:, 0] != kept[:, 2])
                    self.snaps += int((~live & whole).sum())    # a face the server no longer has
                    self.kept[mat] = list(kept[live])

    def _going_points(self) -> np.ndarray:
        """(e,) bool: the points on their way onto an anchor."""
        going = np.zeros(len(self.point_target), bool)
        going[[p for p, m in self.active.items() if m.end is not None]] = True
        return going

    def _going(self, tri) -> bool:
        """Whether a vertex of ``tri`` is on its way onto an anchor."""
        return any((m := self.active.get(int(self.point[v]))) is not None and m.end is not None for v in tri)

    def _drop_triangles_of(self, p: int) -> None:
        verts = set(self._vertices([p]).tolist())
        for mat in range(self.materials):
            for slot in [s for s, t in self.held[mat].items() if any(int(v) in verts for v in t)]:
                del self.held[mat][slot]
            self.kept[mat] = [t for t in self.kept[mat] if not any(int(v) in verts for v in t)]

    def _emit(self, out: Changes, surfaces, touched: set = frozenset()) -> None:
        """One display write per material that changed: the frame's writes (held slots showing their
        triangles), slots whose hold changed, and the kept triangles after the buffer."""
        mats = {s.material for s in surfaces} | {m for m, _ in touched}
        mats |= {m for m in range(self.materials) if self.kept[m] or self._shown_kept[m]}
        for m in sorted(mats):
            count = len(self.rows[m])
            slots = [int(x) for s in surfaces if s.material == m for x in np.asarray(s.slots, np.int64)]
            slots += [slot for mm, slot in touched if mm == m and slot < count]
            slots += list(self.held[m])
            slots = np.array(sorted(set(slots)), np.int64)
            tris = self.rows[m][slots] if len(slots) else np.zeros((0, 3), np.int64)
            for i, slot in enumerate(slots.tolist()):
                if slot in self.held[m]:
                    tris[i] = self.held[m][slot]
            kept = np.array(self.kept[m], np.int64).reshape(-1, 3)
            if len(kept) or self._shown_kept[m]:
                slots = np.r_[slots, np.arange(count, count + len(kept))]
                tris = np.concatenate([tris, kept])
            self._shown_kept[m] = len(kept)
            out.writes.append((m, count + len(kept), slots, tris.astype(np.uint32)))

    def _vertices(self, points) -> np.ndarray:
        """(k,) the vertices of ``points``, point by point."""
        points = np.asarray(points, np.int64)
        if not len(points):
            return np.zeros(0, np.int64)
        start, end = self._start[points], self._start[points + 1]
        idx = np.repeat(start - np.r_[0, np.cumsum(end - start)[:-1]], end - start) + np.arange((end - start).sum())
        return self._members[idx]


def points_of(positions: np.ndarray, targets: np.ndarray) -> tuple:
    """The points of a vertex buffer: ``(vertex_point (d,), point_target (e,), start (e + 1,),
    members (d,))``: each vertex's point (vertices with equal coordinates share one), each point's
    target point (the point of its first vertex's morph target; itself where none), and the
    vertices of point ``p``, ``members[start[p]:start[p + 1]]``."""
    positions = np.asarray(positions, np.float32)
    targets = np.asarray(targets, np.int64).reshape(-1)
    if not len(positions):
        return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(1, np.int64), np.zeros(0, np.int64)
    _, first, point = np.unique(positions, axis=0, return_index=True, return_inverse=True)
    point = point.reshape(-1).astype(np.int64)
    members = np.argsort(point, kind="stable")
    start = np.r_[0, np.cumsum(np.bincount(point, minlength=len(first)))]
    return point, point[targets[first]], start, members


def pixels_per_unit(height: float, fov_y: float) -> float:
    """Pixels a unit spans at distance 1 in a viewport ``height`` pixels high with a vertical field of
    view of ``fov_y`` degrees: height / (2 tan(fov_y / 2)), as :class:`caveclod.View` converts errors."""
    return height / (2.0 * math.tan(math.radians(fov_y) / 2.0))


def _apart(a, b) -> float:
    """The distance between points ``a`` and ``b`` (3,), summed in the order the page's port sums it."""
    x, y, z = float(b[0]) - float(a[0]), float(b[1]) - float(a[1]), float(b[2]) - float(a[2])
    return math.sqrt(x * x + y * y + z * z)


def joined(surfaces) -> list:
    """A camera's writes of one frame with one entry per material: the pieces a frame larger than a
    part brings (each a row range of one surface, with the buffer's count; caveclod.frames.frame_parts)
    joined in order. Geomorphs read a material's writes as one: fed a keyframe piece by piece, each
    piece emptied the buffer the one before had filled."""
    pieces: dict[int, list] = {}
    for s in surfaces:
        pieces.setdefault(int(s.material), []).append(s)
    out = []
    for m, ps in pieces.items():
        if len(ps) == 1:
            out.append(ps[0])
            continue
        out.append(Surface(m, int(ps[-1].count), np.concatenate([np.asarray(p.slots, np.int64) for p in ps]),
                           np.concatenate([np.asarray(p.tris, np.int64).reshape(-1, 3) for p in ps])))
    return out


def _key(tri) -> tuple:
    """A triangle up to rotation (the same face whichever corner comes first)."""
    a, b, c = (int(x) for x in tri)
    return min((a, b, c), (b, c, a), (c, a, b))
