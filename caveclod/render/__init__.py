"""GPU rendering of a thin client's index buffers (moderngl, offscreen through EGL).

One :class:`Renderer` owns every GL resource: the vertex buffer, uploaded once
and resident; an index buffer per (camera, material), patched in place from
each frame's slot writes; a texture per material; the shaders. It draws 1-4
cameras as the quadrants of one image::

    from caveclod.render import Renderer, Vertices
    r = Renderer(1280, 720, Vertices(positions, normals, uvs, colors), ["water", "grass"], cameras=2)
    r.apply(camera, material, count, tris, slots)       # one SurfaceDelta of a frame
    r.reset(camera)                                      # before a keyframe
    image = r.render([pose_a, pose_b], wireframe=False)  # (720, 1280, 3) uint8
    save_png("frame.png", image)

Cache mode (a client holding N vertex slots per camera, not the buffer)::

    r = Renderer(1280, 720, None, materials, bounds=(lo, hi), cache_vertices=N)
    r.write_vertices(camera, slots, positions, normals, uvs)   # one VertexWrites, patched in place
    r.apply(camera, material, count, tris, slots)               # tris are slot numbers

Images go out with :func:`save_png`, :func:`save_animation` (animated PNG or
GIF) and :func:`contact_sheet`. Only numpy, moderngl and Pillow are imported.

Over the service: :mod:`.session` (``SessionRenderer``, a renderer kept equal
to a client session's buffers), :mod:`.flight` (fly a session's cameras
along a path, frame by frame), :mod:`.record` (``caveclod render``) and
:mod:`.window` (``caveclod view``, a GLFW window).
"""

from .buffers import UploadStats
from .camera import Camera, quadrants
from .context import RenderError, create_context
from .images import contact_sheet, save_animation, save_png
from .renderer import Renderer, Vertices

__all__ = ["Renderer", "Vertices", "Camera", "UploadStats", "RenderError", "create_context", "quadrants",
           "save_png", "save_animation", "contact_sheet"]


def __getattr__(name: str):
    """``SessionRenderer`` on first use (the README's ``from caveclod.render import SessionRenderer``):
    imported here it would bring the client (grpc) into every import of the renderer."""
    if name == "SessionRenderer":
        from .session import SessionRenderer
        return SessionRenderer
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
