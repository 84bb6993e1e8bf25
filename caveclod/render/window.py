"""``caveclod view``: an interactive window flying a camera through a server.

GLFW makes the window and its OpenGL 3.3 context (the ``glfw`` wheel carries
the library); the same :class:`~caveclod.render.session.SessionRenderer` as
``caveclod render`` draws into it. Camera 1 follows the mouse and keys
(:class:`FlyController`); cameras 2-4, when asked for, fly the flyover path
beside it as quadrants. Poses go out at most 30 times a second and only when
a camera moved; every frame that has arrived is applied before each draw,
without waiting for one, so the window stays responsive when the server is
slow.
"""

from __future__ import annotations

import math
import os
import time

from ..errors import InputError
from ..paths import flyover
from .context import RenderError, create_context

POSE_INTERVAL = 1.0 / 30.0     # seconds between poses of a camera
LOOK_DEGREES_PER_PIXEL = 0.15


class FlyController:
    """A free-flying camera: a position and a heading (yaw, pitch), z up.

    Args:
        eye: (3,) start position. target: (3,) a point it starts looking at.
        speed: world units per second of the move keys.
    """

    def __init__(self, eye, target, speed: float):
        self.eye = [float(v) for v in eye]
        d = [t - e for t, e in zip(target, eye)]
        self.yaw = math.degrees(math.atan2(d[1], d[0]))
        self.pitch = math.degrees(math.atan2(d[2], math.hypot(d[0], d[1])))
        self.speed = float(speed)

    def forward(self) -> tuple:
        """Unit viewing direction."""
        y, p = math.radians(self.yaw), math.radians(self.pitch)
        return (math.cos(p) * math.cos(y), math.cos(p) * math.sin(y), math.sin(p))

    def move(self, forward: float, right: float, up: float, seconds: float) -> None:
        """Move along the view (``forward``), sideways and vertically; each in -1..1, for ``seconds``."""
        f = self.forward()
        y = math.radians(self.yaw)
        r = (math.sin(y), -math.cos(y), 0.0)
        step = self.speed * seconds
        for i in range(3):
            self.eye[i] += step * (forward * f[i] + right * r[i] + up * (i == 2))

    def look(self, dx_pixels: float, dy_pixels: float) -> None:
        """Turn by a mouse drag: right/down in pixels turns right/down. Pitch stays within +-89 degrees."""
        self.yaw -= LOOK_DEGREES_PER_PIXEL * dx_pixels
        self.pitch = max(-89.0, min(89.0, self.pitch - LOOK_DEGREES_PER_PIXEL * dy_pixels))

    def pose(self) -> tuple:
        """``(eye, target, up)``: the target one unit ahead."""
        f = self.forward()
        eye = tuple(self.eye)
        return eye, tuple(e + d for e, d in zip(eye, f)), (0.0, 0.0, 1.0)


def check_display() -> None:
    """RenderError unless a display (X11 or Wayland) is there to open a window on."""
    if not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
        raise RenderError("caveclod view opens a window, and there is no display here (DISPLAY and WAYLAND_DISPLAY "
                          "are unset): run it on a desktop, over 'ssh -X', or on a virtual screen "
                          "('xvfb-run -a caveclod view ...'); 'caveclod render' writes images without a display")


def open_window(width: int, height: int, title: str):
    """A GLFW window with a current OpenGL 3.3 core context; RenderError naming why not."""
    import glfw
    check_display()
    if not glfw.init():
        code, text = glfw.get_error()
        raise RenderError(f"cannot start GLFW on display {os.environ.get('DISPLAY') or os.environ.get('WAYLAND_DISPLAY')}"
                          f": {text.decode(errors='replace') if isinstance(text, bytes) else text}")
    glfw.window_hint(glfw.CONTEXT_VERSION_MAJOR, 3)
    glfw.window_hint(glfw.CONTEXT_VERSION_MINOR, 3)
    glfw.window_hint(glfw.OPENGL_PROFILE, glfw.OPENGL_CORE_PROFILE)
    glfw.window_hint(glfw.OPENGL_FORWARD_COMPAT, True)
    window = glfw.create_window(width, height, title, None, None)
    if not window:
        glfw.terminate()
        raise RenderError("the display offers no OpenGL 3.3 core context for a window; update the graphics driver "
                          "(Mesa 20 or later renders without a GPU)")
    glfw.make_context_current(window)
    glfw.swap_interval(1)
    return window


def main(args) -> int:
    """``caveclod view``: run the window until it is closed (or ``--frames`` draws)."""
    from .record import cache_options, parse_size
    size = parse_size(args.size)
    cache = cache_options(args)
    if not 1 <= args.cameras <= 4:
        raise InputError(f"--cameras must be 1 to 4, got {args.cameras}")
    if args.frames is not None and args.frames < 1:
        raise InputError(f"--frames must be at least 1, got {args.frames}")
    check_display()             # before connecting: fail fast, with the fix
    import glfw

    from ..client import Client, SessionEnded
    from .camera import quadrants
    from .images import save_png
    from .record import pick_mesh
    from .session import SessionRenderer
    qw, qh = quadrants(*size, args.cameras)[0][2:]
    token = args.token or os.environ.get("CAVECLOD_TOKEN")
    window = open_window(*size, "caveclod view")
    try:
        ctx = create_context(offscreen=False)
        with Client(args.target, token=token, tls_ca=args.tls_ca, cache_dir=args.cache_dir) as client:
            mesh = pick_mesh(client, args.mesh, args.target)
            with client.session(mesh, cameras=args.cameras, width=qw, height=qh, fov_y=args.fov,
                                tolerance_px=args.tolerance, prune=False if args.no_prune else None,
                                strict_bound=True if getattr(args, "strict_bound", False) else None,
                                **cache) as session:
                view = SessionRenderer(session, *size, ctx=ctx, morph_ms=args.morph_ms,
                                       morph_speed=args.morph_speed)
                drawn, image = _loop(glfw, window, ctx, session, view, args)
                if args.screenshot and image is not None:
                    save_png(args.screenshot, image)
                print(f"view: {drawn} frames drawn, {session.protocol.divergences} divergences")
                view.release()
    except SessionEnded as exc:
        raise InputError(f"{args.target}: the session ended: {exc}") from None
    finally:
        glfw.terminate()
    return 0


def _loop(glfw, window, ctx, session, view, args) -> tuple[int, object]:
    """Poll input, send poses, apply arrived frames, draw; returns (frames drawn, last image or None)."""
    import numpy as np
    mesh = session.info.mesh
    lo = (mesh.bounds_min.x, mesh.bounds_min.y, mesh.bounds_min.z)
    hi = (mesh.bounds_max.x, mesh.bounds_max.y, mesh.bounds_max.z)
    extent = max(hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2], 1e-9)
    start = flyover(lo, hi, 0, 0.0)
    fly = FlyController(start.eye, start.target, speed=extent / 20.0)
    state = {"wireframe": bool(args.wireframe), "drag": None}

    def on_key(win, key, scancode, action, mods):
        if action == glfw.PRESS and key == glfw.KEY_ESCAPE:
            glfw.set_window_should_close(win, True)
        elif action == glfw.PRESS and key == glfw.KEY_F:
            state["wireframe"] = not state["wireframe"]

    def on_scroll(win, dx, dy):
        fly.speed *= 1.25 ** dy

    def on_resize(win, w, h):
        if w >= 2 and h >= 2:
            view.renderer.resize(w, h)

    glfw.set_key_callback(window, on_key)
    glfw.set_scroll_callback(window, on_scroll)
    glfw.set_framebuffer_size_callback(window, on_resize)
    keys = {glfw.KEY_W: (1, 0, 0), glfw.KEY_S: (-1, 0, 0), glfw.KEY_D: (0, 1, 0), glfw.KEY_A: (0, -1, 0),
            glfw.KEY_E: (0, 0, 1), glfw.KEY_Q: (0, 0, -1)}
    t0 = last = time.perf_counter()
    sent_at, sent_pose = 0.0, None
    drawn, image = 0, None
    while not glfw.window_should_close(window) and (args.frames is None or drawn < args.frames):
        glfw.poll_events()
        now = time.perf_counter()
        dt, last = now - last, now
        move = [sum(v[i] for k, v in keys.items() if glfw.get_key(window, k) == glfw.PRESS) for i in range(3)]
        if any(move):
            fly.move(*move, dt)
        if glfw.get_mouse_button(window, glfw.MOUSE_BUTTON_LEFT) == glfw.PRESS:
            x, y = glfw.get_cursor_pos(window)
            if state["drag"] is not None:
                fly.look(x - state["drag"][0], y - state["drag"][1])
            state["drag"] = (x, y)
        else:
            state["drag"] = None
        poses = [fly.pose()] + [tuple(flyover(lo, hi, c, now - t0)) for c in range(1, view.cameras)]
        if now - sent_at >= POSE_INTERVAL and (poses[0] != sent_pose or view.cameras > 1):
            for c, (eye, target, up) in enumerate(poses):
                if c > 0 or poses[0] != sent_pose:
                    session.send_pose(c, eye, target, up)
            sent_at, sent_pose = now, poses[0]
        while (update := session.next_frame(timeout=0)) is not None:
            view.apply(update, now=now - t0)
        view.advance(now - t0)
        view.renderer.draw(view.views(poses), wireframe=state["wireframe"], target=ctx.screen)
        drawn += 1
        if args.screenshot and (args.frames is None or drawn == args.frames):
            raw = ctx.screen.read(components=3, alignment=1)
            image = np.frombuffer(raw, np.uint8).reshape(view.renderer.height, view.renderer.width, 3)[::-1].copy()
        glfw.swap_buffers(window)
        faces = sum(sum(view.renderer.counts(c)) for c in range(view.cameras))
        glfw.set_window_title(window, f"caveclod view: {mesh.name}, {faces:,} triangles, speed {fly.speed:,.0f}/s")
    return drawn, image
