"""The renderer: one object owning every GL resource of a thin client.

The vertex buffer is uploaded once and stays resident; each (camera,
material) pair has an index buffer patched in place by the frames
(:mod:`caveclod.render.buffers`). Cameras are drawn as the quadrants of one
image (Kram & Shaw's figures), each with its own view and index buffers, all
over the one vertex buffer. In cache mode (``cache_vertices=N``) there is no
vertex buffer: each camera has N vertex slots, patched in place by the
frames' vertex writes (:mod:`caveclod.render.slots`), and its index buffers
hold slot numbers.
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import moderngl
import numpy as np

from . import shaders
from .buffers import IndexBuffer, UploadStats, slot_runs
from .camera import Camera, quadrants
from .context import create_context
from .slots import SlotVertices
from .textures import check_texture, material_texture

MAX_CAMERAS = 4
BACKGROUND = (0.56, 0.66, 0.78)      # a pale sky, far from every generated texture
EDGE_COLOR = (0.05, 0.05, 0.08)
LIGHT = (0.60, 0.35, 0.72)           # towards the light: 46 degrees up, so relief shows
AMBIENT = 0.35


class Vertices(NamedTuple):
    """The planar vertex buffer as the wire and the ``.cvc`` file lay it out.

    positions (d, 3) float32, normals (d, 3) float32, uvs (d, 2) float32,
    colors (d, 4) uint8 RGBA or None (also None when given as (0, 4)).
    """

    positions: np.ndarray
    normals: np.ndarray
    uvs: np.ndarray
    colors: np.ndarray | None = None


def _in_own_context(method):
    """Run ``method`` with the renderer's context current when the renderer made it.

    Each renderer made without ``ctx=`` has an EGL context of its own, and GL
    calls go to whichever context is current on the thread: the last one
    made. A second renderer in one process made the first draw into the
    second's context (its image lost the mesh) and read back the second's
    buffers, so its own check found nothing wrong. The context is made
    current and left so: moderngl's ``with ctx`` leaves EGL's last context
    in an undefined state on exit (images drawn after it varied from run to
    run). A context passed in (a window's, or one shared by several
    renderers) is the caller's to make current.
    """
    @functools.wraps(method)
    def wrapper(self, *args, **kwargs):
        if self._owns_ctx:
            self.ctx.__enter__()            # made current, and left so: EGL's exit does not restore the last
        return method(self, *args, **kwargs)
    return wrapper


class Renderer:
    """Draws 1-4 cameras' index buffers over one resident vertex buffer.

    Args:
        width, height: the image in pixels.
        vertices: a :class:`Vertices` (or the same 3-4 arrays as a tuple);
            None in cache mode.
        materials: material names by id (``water``, ``grass``, ``rock`` and
            ``snow`` get generated textures of their own, others a neutral one).
        cameras: 1 to 4, laid out as :func:`caveclod.render.camera.quadrants`.
        bounds: ``(lo, hi)`` (3,) corners of the scene box, for the clip
            planes; default: the box of the positions.
        ctx: a moderngl context; default: :func:`create_context` offscreen.
        textures: ``{material id: (h, w, 3 | 4) uint8 image}`` to use instead
            of generated textures. Row 0 is v = 0: an image file read top row
            first, for UVs with v = 0 at the bottom (OBJ), goes in as ``image[::-1]``.
        light: direction towards the light (world); ambient: 0..1.
        anisotropy: texture filtering; 1 is trilinear. Higher values sharpen
            terrain seen at grazing angles; free on a GPU, but 4 makes a
            1280x720 frame 2.4 times slower on llvmpipe.
        cache_vertices: cache mode: N vertex slots per camera instead of a
            vertex buffer (``vertices`` None, ``bounds`` required: the
            MeshInfo's box); frames' vertex writes go in with
            :meth:`write_vertices`, and index buffers hold slot numbers.
        colors: cache mode: whether vertices carry colours (the
            VertexFormat lists ATTRIBUTE_SEMANTIC_COLOR).
        morph: geomorphs: each camera draws from a position buffer of its
            own, whose moving vertices :meth:`write_positions` updates
            (:mod:`caveclod.client.geomorph`); normals, uvs and colours stay
            shared. Not in cache mode.

    Frames go in with :meth:`apply` and :meth:`reset` (and in cache mode
    :meth:`write_vertices`), images come out of :meth:`render`;
    :attr:`stats` counts every byte sent to the GPU.
    """

    def __init__(self, width: int, height: int, vertices, materials, *, cameras: int = 1, bounds=None,
                 ctx: moderngl.Context | None = None, textures: dict | None = None,
                 light=LIGHT, ambient: float = AMBIENT, anisotropy: float = 1.0,
                 cache_vertices: int | None = None, colors: bool = False, morph: bool = False):
        # Everything is checked before the first GL object is made.
        _check_size(width, height)
        if not (isinstance(cameras, (int, np.integer)) and 1 <= cameras <= MAX_CAMERAS):
            raise ValueError(f"cameras must be 1 to {MAX_CAMERAS}, got {cameras!r}")
        if cache_vertices is None:
            vertices = _check_vertices(vertices)
            with_colors = vertices.colors is not None
        else:
            _check_cache(cache_vertices, vertices, bounds)
            with_colors = bool(colors)
        if morph and cache_vertices is not None:
            raise ValueError("geomorphs need the resident vertex buffer; cache mode has none")
        self.morph = bool(morph)
        self.materials = [str(name) for name in materials]
        if not self.materials:
            raise ValueError("a renderer needs at least one material name")
        images = _texture_images(self.materials, textures or {})
        self.width, self.height, self.cameras = int(width), int(height), int(cameras)
        self.cache_vertices = None if cache_vertices is None else int(cache_vertices)
        self.n_vertices = len(vertices.positions) if cache_vertices is None else self.cache_vertices
        self.lo, self.hi = _check_bounds(bounds, None if vertices is None else vertices.positions)
        self.origin = 0.5 * (self.lo + self.hi)
        self.stats = UploadStats()
        self._owns_ctx = ctx is None
        self.ctx = create_context() if ctx is None else ctx
        if self._owns_ctx:
            self.ctx.__enter__()                # current for what is made below (see _in_own_context)
        self._programs = {
            False: self.ctx.program(vertex_shader=shaders.VERTEX, fragment_shader=shaders.FRAGMENT),
            True: self.ctx.program(vertex_shader=shaders.VERTEX, geometry_shader=shaders.GEOMETRY,
                                   fragment_shader=shaders.FRAGMENT_WIREFRAME),
        }
        if cache_vertices is None:
            self._slots = []
            self._vertex_content = self._upload_vertices(vertices)
            self._contents = [self._vertex_content] * self.cameras      # every camera draws the one buffer
            # (with geomorphs, each its own positions)
        else:
            self._slots = [SlotVertices(self.ctx, self.cache_vertices, with_colors, self.stats)
                           for _ in range(self.cameras)]
            self._vertex_content = []
            self._contents = [slots.content for slots in self._slots]
        self._positions: list = []                     # geomorphs: each camera's position buffer
        if self.morph:
            for c in range(self.cameras):
                buffer = self.ctx.buffer(np.ascontiguousarray(vertices.positions, np.float32))
                self._positions.append(buffer)
                self.stats.vertex_bytes += buffer.size
                self._contents[c] = [(buffer, "3f", "in_position"), *self._vertex_content[1:]]
        self._textures = self._upload_textures(images, anisotropy)
        light = np.asarray(light, dtype=np.float64)
        for program in self._programs.values():
            _set(program, u_texture=0, u_light=tuple(light / np.linalg.norm(light)), u_ambient=float(ambient),
                 u_colors=with_colors, u_origin=tuple(self.origin), u_edge_color=EDGE_COLOR)
        self._buffers = [[IndexBuffer(self.ctx, self.n_vertices, self.stats) for _ in self.materials]
                         for _ in range(self.cameras)]
        self._fbo = self._framebuffer()

    # -- frames in ------------------------------------------------------------
    @_in_own_context
    def apply(self, camera: int, material: int, count, tris, slots=None, first_slot=0) -> None:
        """Apply one ``SurfaceDelta``: resize the (camera, material) buffer to
        ``count`` triangles and write ``tris`` (k, 3) into ``slots`` (k,)
        (ascending), or into ``first_slot ..`` consecutive slots when
        ``slots`` is None.

        Raises:
            ValueError: bad camera/material, shapes, a slot >= count or a
                vertex index >= d; the buffer is then left as it was.
        """
        self._buffer(camera, material).apply(count, tris, slots, first_slot)

    @_in_own_context
    def reset(self, camera: int) -> None:
        """Empty every buffer of ``camera``: a keyframe's first part follows
        (in cache mode it brings every vertex the buffers use again)."""
        for buffer in self._camera_buffers(camera):
            buffer.clear()

    @_in_own_context
    def write_vertices(self, camera: int, slots, positions, normals, uvs, colors=None, first_slot=0) -> None:
        """Cache mode: apply one ``VertexWrites``: write k vertices (positions
        (k, 3), normals (k, 3), uvs (k, 2)[, colors (k, 4) uint8]) into
        ``slots`` (k,) ascending, or into ``first_slot ..`` when ``slots`` is
        None. Each run of consecutive slots is one write per attribute.

        Raises:
            ValueError: not in cache mode, a bad camera, shapes or types, a
                slot >= N; nothing is written then.
        """
        if self.cache_vertices is None:
            raise ValueError("write_vertices() is for cache mode (Renderer(..., cache_vertices=N)); "
                             "this renderer holds the whole vertex buffer")
        self._camera_buffers(camera)
        arrays = (positions, normals, uvs) if colors is None else (positions, normals, uvs, colors)
        self._slots[camera].write(slots, arrays, first_slot)

    @_in_own_context
    def write_positions(self, camera: int, vertices, positions) -> None:
        """Geomorphs: move ``vertices`` (k,) of ``camera`` to ``positions`` (k, 3) (the rows of
        :meth:`caveclod.client.geomorph.Geomorphs.moving`). Each run of consecutive vertices is one write."""
        if not self.morph:
            raise ValueError("write_positions() needs Renderer(..., morph=True)")
        self._camera_buffers(camera)
        v = np.asarray(vertices, np.int64)
        if not len(v):
            return
        if v.min() < 0 or v.max() >= self.n_vertices:
            raise ValueError(f"vertex {int(v.max()) if v.max() >= self.n_vertices else int(v.min())} is outside "
                             f"the vertex buffer of {self.n_vertices}")
        order = np.argsort(v, kind="stable")
        v = v[order]
        last = np.r_[v[1:] != v[:-1], True]                      # a vertex given twice: the last row wins
        v, order = v[last], order[last]
        rows = np.ascontiguousarray(np.asarray(positions, np.float32).reshape(-1, 3)[order])
        data = rows.reshape(-1).view(np.uint8)
        runs = slot_runs(v, 0, len(v))
        for first, a, b in runs:
            self._positions[camera].write(data[a * 12: b * 12], offset=first * 12)
        self.stats.vertex_writes += len(runs)
        self.stats.vertex_bytes += rows.nbytes

    @_in_own_context
    def camera_positions(self, camera: int) -> np.ndarray:
        """Geomorphs: (d, 3) float32 the positions ``camera`` draws, read back from the GPU."""
        if not self.morph:
            raise ValueError("camera_positions() needs Renderer(..., morph=True)")
        self._camera_buffers(camera)
        return np.frombuffer(self._positions[camera].read(), np.float32).reshape(-1, 3)

    @_in_own_context
    def slot_vertices(self, camera: int) -> Vertices:
        """Cache mode: the camera's N slots read back from the GPU (unwritten slots are undefined)."""
        if self.cache_vertices is None:
            raise ValueError("slot_vertices() is for cache mode")
        self._camera_buffers(camera)
        return Vertices(*self._slots[camera].read())

    @_in_own_context
    def index_buffer(self, camera: int, material: int) -> np.ndarray:
        """(count, 3) uint32 triangles of the (camera, material) buffer, read back from the GPU."""
        return self._buffer(camera, material).read()

    @_in_own_context
    def counts(self, camera: int) -> list[int]:
        """Triangles drawn per material for ``camera``."""
        return [buffer.count for buffer in self._camera_buffers(camera)]

    # -- images out -----------------------------------------------------------
    def viewports(self) -> list[tuple[int, int, int, int]]:
        """``(x, y, w, h)`` of each camera's quadrant in the image (origin top left)."""
        return quadrants(self.width, self.height, self.cameras)

    @_in_own_context
    def render(self, views, wireframe: bool = False) -> np.ndarray:
        """Draw every camera's view into its quadrant, offscreen, and read the image back.

        Args:
            views: one per camera: a :class:`Camera`, a ``caveclod.paths.Pose``
                or ``(eye, target, up[, fov_y])``, or anything with ``eye``,
                ``target``, ``up`` and ``fov_y`` attributes.
            wireframe: overlay the triangles' edges.

        Returns:
            (height, width, 3) uint8 RGB image, row 0 at the top.
        """
        self.draw(views, wireframe)
        raw = self._fbo.read(components=3, alignment=1)
        return np.frombuffer(raw, np.uint8).reshape(self.height, self.width, 3)[::-1].copy()

    @_in_own_context
    def draw(self, views, wireframe: bool = False, target: moderngl.Framebuffer | None = None) -> None:
        """Draw as :meth:`render` does into ``target`` (a window's ``ctx.screen``,
        width x height pixels), or into the offscreen image when None; nothing is read back."""
        views = list(views)
        if len(views) != self.cameras:
            raise ValueError(f"draw() needs one view per camera ({self.cameras}), got {len(views)}")
        views = [Camera.of(view) for view in views]
        program = self._programs[bool(wireframe)]
        target = self._fbo if target is None else target
        target.use()
        target.clear(*BACKGROUND, 1.0, depth=1.0)
        self.ctx.enable_only(moderngl.DEPTH_TEST)
        for camera, (view, (x, y, w, h)) in enumerate(zip(views, self.viewports())):
            target.viewport = (x, self.height - y - h, w, h)       # GL's origin is bottom left
            aspect = w / h
            near, far = view.clip_planes(self.lo, self.hi, aspect)
            mvp = view.projection(aspect, near, far) @ view.view_matrix(self.origin)
            _set(program, u_mvp=tuple(mvp.astype(np.float32).T.ravel()), u_half_viewport=(w / 2.0, h / 2.0))
            for material, buffer in enumerate(self._buffers[camera]):
                if buffer.count:
                    self._textures[material].use(0)
                    vao = buffer.vertex_array(program, self._contents[camera])
                    vao.render(moderngl.TRIANGLES, vertices=buffer.count * 3)

    @_in_own_context
    def resize(self, width: int, height: int) -> None:
        """Change the image size (a window was resized); buffers and textures stay."""
        _check_size(width, height)
        self._release_framebuffer()
        self.width, self.height = int(width), int(height)
        self._fbo = self._framebuffer()

    # -- lifetime -------------------------------------------------------------
    def release(self) -> None:
        """Free the GPU resources (and the context when the renderer made it)."""
        self._release_resources()
        if self._owns_ctx:
            self.ctx.release()

    @_in_own_context
    def _release_resources(self) -> None:
        for buffers in self._buffers:
            for buffer in buffers:
                buffer.release()
        for slots in self._slots:
            slots.release()
        for buffer in self._positions:
            buffer.release()
        self._release_framebuffer()
        for resource in [*self._textures, *(buffer for buffer, *_ in self._vertex_content), *self._programs.values()]:
            resource.release()

    def __enter__(self) -> "Renderer":
        return self

    def __exit__(self, *exc) -> None:
        self.release()

    # -- internals ----------------------------------------------------------------
    def _camera_buffers(self, camera) -> list:
        if not (isinstance(camera, (int, np.integer)) and 0 <= camera < self.cameras):
            raise ValueError(f"camera must be 0 .. {self.cameras - 1}, got {camera!r}")
        return self._buffers[camera]

    def _buffer(self, camera, material) -> IndexBuffer:
        buffers = self._camera_buffers(camera)
        if not (isinstance(material, (int, np.integer)) and 0 <= material < len(buffers)):
            raise ValueError(f"material must be 0 .. {len(buffers) - 1}, got {material!r}")
        return buffers[material]

    def _upload_vertices(self, vertices: Vertices) -> list:
        """The one upload of the vertex buffer: a GPU buffer per planar attribute."""
        content = []
        for array, layout, name in ((vertices.positions, "3f", "in_position"), (vertices.normals, "3f", "in_normal"),
                                    (vertices.uvs, "2f", "in_uv"), (vertices.colors, "4f1", "in_color")):
            if array is not None:
                content.append((self.ctx.buffer(array), layout, name))
                self.stats.vertex_bytes += array.nbytes
        return content

    def _upload_textures(self, images: list, anisotropy: float) -> list:
        """One repeating, mipmapped texture per material."""
        textures = []
        for image in images:
            texture = self.ctx.texture((image.shape[1], image.shape[0]), image.shape[2], image.tobytes())
            texture.repeat_x = texture.repeat_y = True
            texture.build_mipmaps()
            texture.anisotropy = max(1.0, min(float(anisotropy), self.ctx.max_anisotropy))
            textures.append(texture)
            self.stats.texture_bytes += image.nbytes
        return textures

    def _framebuffer(self) -> moderngl.Framebuffer:
        size = (self.width, self.height)
        return self.ctx.framebuffer(color_attachments=[self.ctx.renderbuffer(size)],
                                    depth_attachment=self.ctx.depth_renderbuffer(size))

    def _release_framebuffer(self) -> None:
        for resource in (*self._fbo.color_attachments, self._fbo.depth_attachment, self._fbo):
            resource.release()


def _check_size(width, height) -> None:
    if not (isinstance(width, (int, np.integer)) and isinstance(height, (int, np.integer))
            and width >= 2 and height >= 2):
        raise ValueError(f"the image must be at least 2 x 2 pixels, got {width!r} x {height!r}")


def _check_cache(cache_vertices, vertices, bounds) -> None:
    if isinstance(cache_vertices, (bool, np.bool_)) or not isinstance(cache_vertices, (int, np.integer)) \
            or cache_vertices < 1:
        raise ValueError(f"cache_vertices must be a slot count of at least 1, got {cache_vertices!r}")
    if vertices is not None:
        raise ValueError("in cache mode there is no vertex buffer: pass vertices=None, and write vertices into "
                         "slots with write_vertices()")
    if bounds is None:
        raise ValueError("cache mode needs bounds=(lo, hi), the scene box (MeshInfo.bounds_min/max): "
                         "there are no positions to take it from")


def _check_bounds(bounds, positions: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """(lo, hi) float64 (3,) of the scene box given, or of the positions."""
    if bounds is None:
        return positions.min(axis=0).astype(np.float64), positions.max(axis=0).astype(np.float64)
    try:
        lo, hi = (np.asarray(b, dtype=np.float64).reshape(3) for b in bounds)
    except (TypeError, ValueError):
        raise ValueError(f"bounds are (lo, hi), three numbers each; got {bounds!r}") from None
    if not (np.isfinite(lo).all() and np.isfinite(hi).all() and (lo <= hi).all()):
        raise ValueError(f"bounds must be finite with lo <= hi, got {lo} .. {hi}")
    return lo, hi


def _texture_images(materials: list, given: dict) -> list:
    """(h, w, 3 | 4) uint8 image per material: the one given, else a generated one."""
    unknown = set(given) - set(range(len(materials)))
    if unknown:
        raise ValueError(f"textures given for unknown material ids {sorted(unknown)}")
    return [check_texture(given[m]) if m in given else material_texture(name) for m, name in enumerate(materials)]


def _check_vertices(vertices) -> Vertices:
    """The planar arrays as contiguous float32 / uint8, or ``ValueError`` naming what is off."""
    parts = tuple(vertices)
    if len(parts) not in (3, 4):
        raise ValueError("vertices are (positions, normals, uvs[, colors])")
    positions, normals, uvs = (np.ascontiguousarray(a, dtype=np.float32) for a in parts[:3])
    colors = parts[3] if len(parts) == 4 else None
    d = len(positions)
    if d == 0:
        raise ValueError("the vertex buffer is empty")
    for name, array, width in (("positions", positions, 3), ("normals", normals, 3), ("uvs", uvs, 2)):
        if array.shape != (d, width):
            raise ValueError(f"vertex {name} must have shape ({d}, {width}), got {array.shape}")
        if not np.isfinite(array).all():
            raise ValueError(f"vertex {name} hold NaN or infinite values")
    if colors is not None:
        colors = np.asarray(colors)
        if colors.shape == (0, 4):
            colors = None
        elif colors.shape != (d, 4) or colors.dtype != np.uint8:
            raise ValueError(f"vertex colors must be ({d}, 4) uint8 or None, got {colors.dtype} {colors.shape}")
        else:
            colors = np.ascontiguousarray(colors)
    return Vertices(positions, normals, uvs, colors)


def _set(program: moderngl.Program, **uniforms) -> None:
    """Set the uniforms ``program`` has (each program uses a subset)."""
    for name, value in uniforms.items():
        if name in program:
            program[name].value = value
