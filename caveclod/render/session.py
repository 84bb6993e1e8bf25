"""A renderer fed by a client session: the GPU mirror of the client library's buffers.

:class:`SessionRenderer` makes a :class:`~caveclod.render.Renderer` from a
session's vertex buffer and mesh description (materials, bounds) and applies
every frame the client library applied, surface by surface, in the same
order::

    with Client(target) as client, client.session("terrain", cameras=4, width=640, height=360) as s:
        view = SessionRenderer(s, 1280, 720)
        s.send_pose(0, eye, target)
        view.apply(s.next_frame(timeout=1.0))
        image = view.render([pose_a, pose_b, pose_c, pose_d])

The client library checks every frame's CRCs; the GPU buffers receive the
exact slot writes it applied, so after each frame they hold the same
triangles (:meth:`SessionRenderer.mismatches` reads them back to prove it).

With geomorphs (``morph_ms > 0`` and a session opened with
``morph_targets=True``), splits and collapses change the shape over
``morph_ms`` instead of popping (:mod:`caveclod.client.geomorph`): the GPU
then holds each camera's *display* buffers (the client's, with the
triangles of collapses still under way) and its own positions, and
:meth:`SessionRenderer.render` takes the time to draw them at.

A cache-mode session (``cache_vertices=N``) has no vertex buffer: the
renderer gets N vertex slots per camera, and each frame's vertex writes go
into them before its index writes, as the client library applies them.
"""

from __future__ import annotations

import time

import numpy as np

from ..client.geomorph import Geomorphs, pixels_per_unit, points_of
from ..wire import Surface
from .camera import Camera
from .renderer import Renderer, Vertices


class SessionRenderer:
    """A :class:`Renderer` kept equal to a client session's index buffers.

    Args:
        session: a :class:`caveclod.client.Session` (or an object with the same
            ``protocol``, ``vertex_buffer`` and ``info`` attributes, such as
            the asyncio session) whose vertex buffer has arrived, or in
            cache mode whose SessionInfo has.
        width, height: image size in pixels; the cameras share it as quadrants.
        fov_y: vertical field of view in degrees (default: the session's).
        morph_ms: geomorph duration; 0 (or a session without morph targets): none.
        morph_speed: None, or pixels a second: each morph then takes its path on
            screen (seen from the camera's last rendered pose) over it, at most
            ``morph_ms`` (:class:`caveclod.client.geomorph.Geomorphs`).
        **renderer_options: passed to :class:`Renderer` (``ctx``, ``textures``, ...).
    """

    def __init__(self, session, width: int, height: int, *, fov_y: float | None = None, morph_ms: float = 0.0,
                 morph_speed: float | None = None, **renderer_options):
        self.session = session
        self.morphs = None                     # per camera: Geomorphs, when morphing
        info = session.info
        self.fov_y = float(fov_y if fov_y is not None else (info.options.fov_y_deg or 60.0))
        lo = (info.mesh.bounds_min.x, info.mesh.bounds_min.y, info.mesh.bounds_min.z)
        hi = (info.mesh.bounds_max.x, info.mesh.bounds_max.y, info.mesh.bounds_max.z)
        names = [m.name for m in sorted(info.mesh.materials, key=lambda m: m.id)]
        if info.cache_vertices:
            colors = session.protocol.slots[0].colors is not None
            self.renderer = Renderer(width, height, None, names, cameras=int(info.cameras), bounds=(lo, hi),
                                     cache_vertices=int(info.cache_vertices), colors=colors, **renderer_options)
        else:
            vb = session.vertex_buffer
            morph = morph_ms > 0 and vb.morph_targets is not None
            self.renderer = Renderer(width, height, Vertices(vb.positions, vb.normals, vb.uvs, vb.colors), names,
                                     cameras=int(info.cameras), bounds=(lo, hi), morph=morph, **renderer_options)
            if morph:
                points = points_of(vb.positions, vb.morph_targets)
                self.morphs = [Geomorphs(vb.positions, vb.morph_targets, len(names), morph_ms / 1000.0, points,
                                         speed=morph_speed) for _ in range(int(info.cameras))]
        # Pixels a unit spans at distance 1 in the viewport the server refines for (the tolerance's pixels).
        self._kappa = pixels_per_unit(info.options.viewport_height or height, self.fov_y)
        self._started = time.monotonic()
        self.time = 0.0                        # the geomorphs' clock when a frame was last applied
        self._epoch = session.protocol.epoch
        self._replay()

    @property
    def cameras(self) -> int:
        return self.renderer.cameras

    def apply(self, update, now: float | None = None) -> None:
        """Apply one :class:`caveclod.client.FrameUpdate` (None: nothing) to the GPU buffers; ``now``:
        seconds on the geomorphs' clock (default: seconds since this renderer was made; give path
        time instead to render a flight frame by frame)."""
        self.time = self.clock() if now is None else float(now)
        if self.session.protocol.epoch != self._epoch:
            # The server started the session over (its token expired during
            # a reconnect): the client's buffers were emptied, so are ours.
            self._epoch = self.session.protocol.epoch
            for c in range(self.cameras):
                self.renderer.reset(c)
                if self.morphs is not None:       # nothing of the old session morphs on
                    self.morphs[c].apply([], True, self.time)
        if update is None:
            return
        for c, cam in sorted(update.cameras.items()):
            if cam.keyframe:
                self.renderer.reset(c)
            for w in cam.vertex_writes:          # cache mode: before the index writes that use them
                self.renderer.write_vertices(c, w.slots, *w.blocks)
            if self.morphs is None:
                for s in cam.surfaces:
                    self.renderer.apply(c, s.material, s.count, s.tris, s.slots)
            else:
                self._display(c, self.morphs[c].apply(cam.surfaces, cam.keyframe, self.time, posed=cam.pose_seq > 0))

    def clock(self) -> float:
        """Seconds since this renderer was made: the geomorphs' clock when none is given."""
        return time.monotonic() - self._started

    def advance(self, now: float) -> None:
        """Geomorphs: bring every camera's display and positions to time ``now`` (before drawing)."""
        if self.morphs is None:
            return
        for c, morphs in enumerate(self.morphs):
            self._display(c, morphs.tick(now))
            self.renderer.write_positions(c, *morphs.moving(now))

    def _display(self, camera: int, changes) -> None:
        for m, count, slots, tris in changes.writes:
            self.renderer.apply(camera, m, count, tris, slots)

    def views(self, poses) -> list[Camera]:
        """One :class:`Camera` per pose (a Pose or ``(eye, target, up)``, a Camera or a View, as
        :meth:`Camera.of` takes them), with the session's field of view: the one its server refines for."""
        cams = [Camera.of(p, self.fov_y) for p in poses]
        return [Camera(c.eye, c.target, c.up, self.fov_y) for c in cams]

    def render(self, poses, wireframe: bool = False, now: float | None = None) -> np.ndarray:
        """(height, width, 3) uint8 image of every camera at its pose (one per camera), the geomorphs
        at ``now`` (default: :meth:`clock`)."""
        self.advance(self.clock() if now is None else float(now))
        cams = self.views(poses)
        if self.morphs is not None:            # the next frames' morphs are timed from these poses
            for morphs, cam in zip(self.morphs, cams):
                morphs.look_from(cam.eye, self._kappa)
        return self.renderer.render(cams, wireframe=wireframe)

    def mismatches(self) -> list[tuple[int, int]]:
        """(camera, material) pairs whose GPU buffer, read back, differs from the client library's
        (with geomorphs: from the display, whose logical copy differs from the client library's);
        in cache mode also (camera, -1) where a slot the client holds differs on the GPU."""
        protocol = self.session.protocol
        if self.morphs is None:
            out = [(c, m) for c in range(self.cameras) for m in range(len(self.renderer.materials))
                   if not np.array_equal(self.renderer.index_buffer(c, m), protocol.buffers.buffer(c, m))]
        else:                # the GPU holds the display; the morphs' own copy is the client's buffer
            out = [(c, m) for c in range(self.cameras) for m in range(len(self.renderer.materials))
                   if not np.array_equal(self.renderer.index_buffer(c, m), self.morphs[c].display(m))
                   or not np.array_equal(self.morphs[c].rows[m], protocol.buffers.buffer(c, m))]
        if protocol.slots is not None:
            for c in range(self.cameras):
                held = protocol.slots[c].held          # other slots are stale on both sides: never drawn
                gpu = self.renderer.slot_vertices(c)
                mine = protocol.slots[c]
                pairs = [(gpu.positions, mine.positions), (gpu.normals, mine.normals), (gpu.uvs, mine.uvs)]
                if mine.colors is not None:
                    pairs.append((gpu.colors, mine.colors))
                if not all(np.array_equal(a[held], b[held]) for a, b in pairs):
                    out.append((c, -1))
        return sorted(out)

    def release(self) -> None:
        self.renderer.release()

    def __enter__(self) -> "SessionRenderer":
        return self

    def __exit__(self, *exc) -> None:
        self.release()

    def _replay(self) -> None:
        """Upload what the client already holds (a renderer made mid-session), once, whole."""
        buffers = self.session.protocol.buffers
        slots = self.session.protocol.slots
        for c in range(self.cameras):
            if slots is not None and slots[c].n_held:
                held = np.flatnonzero(slots[c].held)
                self.renderer.write_vertices(c, held, *(a[held] for a in slots[c].arrays.values()))
            held = []
            for m in range(len(self.renderer.materials)):
                buf = buffers.buffer(c, m)
                if len(buf):
                    self.renderer.apply(c, m, len(buf), buf, None, 0)
                    held.append(Surface(m, len(buf), np.arange(len(buf)), buf))
            if self.morphs is not None:           # what is held now appears as it is
                self.morphs[c].apply(held, True, self.time)
