"""Fly a session's cameras along a path through the service and render each frame.

The loop of ``caveclod render`` and ``caveclod demo``: for frame k, every
camera is sent its pose at path time k / fps; frames are received (and
applied to the GPU buffers) until one answers those poses; then the
quadrant image is drawn. Poses go out in lock-step with the frames, so the
flight is the same however fast the machine renders: the latency measured is
the service's answer to a pose, not the renderer's backlog.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from ..paths import PATHS
from .session import SessionRenderer


class FlightError(Exception):
    """The service stopped answering, or the GPU buffers left the client's (one line)."""


@dataclass
class FlightFrame:
    """One drawn frame of a flight.

    Attributes:
        index: 0, 1, ... t: path time in seconds.
        poses: one ``(eye, target, up)`` per camera.
        image: (h, w, 3) uint8 quadrant image, or None when not drawn.
        frames: FrameUpdates applied since the previous drawn frame (the one
            answering the poses last; follow-up frames of cameras still
            refining before it).
        latency_ms: per camera, pose -> frame milliseconds (None: answered by a later pose).
        operations: per camera, splits + collapses in those frames.
        active_faces: per camera, faces after them.
        nbytes: serialized bytes of those frames.
        diverged: CRC mismatches the client library found in them.
        draw_ms: milliseconds to draw the image and read it back.
    """

    index: int
    t: float
    poses: list
    image: np.ndarray | None
    frames: list = field(default_factory=list)
    latency_ms: list = field(default_factory=list)
    operations: list = field(default_factory=list)
    active_faces: list = field(default_factory=list)
    nbytes: int = 0
    diverged: int = 0
    draw_ms: float = 0.0


def path_poses(path: str, lo, hi, cameras: int, t: float) -> list:
    """``(eye, target, up)`` of each camera on ``path`` (a :data:`caveclod.paths.PATHS` name) at time ``t``."""
    try:
        fn = PATHS[path]
    except KeyError:
        raise ValueError(f"unknown trajectory {path!r}; choose one of {', '.join(sorted(PATHS))}") from None
    return [tuple(fn(lo, hi, c, t)) for c in range(cameras)]


def fly(session, view: SessionRenderer, path: str, frames: int, *, fps: float = 30.0, wireframe: bool = False,
        draw: bool = True, verify: bool = False, timeout: float = 30.0):
    """Yield a :class:`FlightFrame` per frame of a ``frames``-frame flight along ``path``.

    Args:
        session: an open :class:`caveclod.client.Session` (blocking client).
        view: the :class:`SessionRenderer` of that session.
        fps: path time between frames is 1 / fps seconds.
        draw: render each frame's image (False: only apply the frames).
        verify: after every frame, read the GPU index buffers (and vertex slots) back and
            compare them with the client library's; FlightError on a difference.
        timeout: seconds to wait for the frame answering a pose.

    Raises:
        FlightError: no frame answered a pose within ``timeout``, or ``verify`` found a difference.
        caveclod.client.SessionEnded: the session ended for good.
    """
    info = session.info.mesh
    lo = (info.bounds_min.x, info.bounds_min.y, info.bounds_min.z)
    hi = (info.bounds_max.x, info.bounds_max.y, info.bounds_max.z)
    n = view.cameras
    for k in range(frames):
        t = k / fps
        poses = path_poses(path, lo, hi, n, t)
        last = 0
        for c, (eye, target, up) in enumerate(poses):
            last = session.send_pose(c, eye, target, up)
        record = FlightFrame(k, t, poses, None, latency_ms=[None] * n, operations=[0] * n, active_faces=[0] * n)
        deadline = time.monotonic() + timeout
        while True:
            update = session.next_frame(timeout=max(deadline - time.monotonic(), 0.0))
            if update is None:
                raise FlightError(f"no frame answered pose {last} within {timeout:g} s; the server is overloaded "
                                  "or stuck: check its log")
            view.apply(update, now=t)             # geomorphs run on path time
            record.frames.append(update)
            record.nbytes += update.nbytes
            record.diverged += len(update.diverged)
            for c, cam in update.cameras.items():
                if cam.latency is not None:
                    record.latency_ms[c] = 1000.0 * cam.latency
                if cam.stats is not None:
                    record.operations[c] += cam.stats.splits + cam.stats.collapses
                    record.active_faces[c] = cam.stats.active_faces
            if update.pose_seq >= last:
                break
        if verify:
            bad = view.mismatches()
            if bad:
                raise FlightError(f"frame {k}: the GPU buffers of (camera, material) {bad} differ from the "
                                  "client library's (material -1: the camera's vertex slots)")
        if draw:
            started = time.perf_counter()
            record.image = view.render(poses, wireframe=wireframe, now=t)
            record.draw_ms = 1000.0 * (time.perf_counter() - started)
        yield record
