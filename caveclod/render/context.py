"""The OpenGL context every renderer object is made in.

Offscreen, the context comes from EGL without a display (Mesa's llvmpipe
where there is no GPU), so renders run on servers and in CI. On a desktop a
window library makes the context; :func:`create_context` then attaches to the
one current on this thread.
"""

from __future__ import annotations

import moderngl

from ..errors import CaveclodError

GL_VERSION = 330
"""OpenGL 3.3 core: geometry shaders (the wireframe overlay) and everything else used."""

INSTALL_HINT = ("install OpenGL and EGL (on Debian/Ubuntu: apt-get install libegl1 libgl1-mesa-dri; "
                "Mesa's llvmpipe renders without a GPU)")


class RenderError(CaveclodError):
    """The renderer cannot run here (no OpenGL) or was used wrongly."""


def create_context(offscreen: bool = True) -> moderngl.Context:
    """An OpenGL 3.3+ context.

    Args:
        offscreen: True: a standalone context through EGL, with no window or
            display. False: the context a window library has made current on
            this thread (``caveclod view``).

    Raises:
        RenderError: no usable OpenGL here; the message names what to install.
    """
    try:
        if offscreen:
            return moderngl.create_context(standalone=True, backend="egl", require=GL_VERSION)
        return moderngl.create_context(require=GL_VERSION)
    except Exception as exc:   # moderngl/glcontext raise plain Exceptions with the loader's text
        where = "an offscreen EGL context" if offscreen else "the window's current context"
        raise RenderError(f"cannot create {where} with OpenGL {GL_VERSION // 100}.{GL_VERSION // 10 % 10}: "
                          f"{exc}; {INSTALL_HINT}") from exc
