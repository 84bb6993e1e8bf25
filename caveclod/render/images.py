"""Rendered frames to files a person opens without extra software.

PNG stills, animations as animated PNG (lossless) or GIF (256 colours, opens
everywhere), and contact sheets: frames in a grid, for a report.
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw

ANIMATION_SUFFIXES = (".png", ".apng", ".gif")


def save_png(path: str | os.PathLike, image: np.ndarray, compress_level: int = 3) -> Path:
    """Write an (h, w, 3 | 4) uint8 image as PNG; returns the path.

    ``compress_level`` 0-9 (zlib): 3 wrote a 1280x720 terrain frame 2.4 times
    faster than Pillow's default of 6 (0.19 s), for a file 13% larger.
    """
    path = Path(path)
    Image.fromarray(_checked(image)).save(path, format="PNG", compress_level=compress_level)
    return path


def save_animation(path: str | os.PathLike, frames, fps: float = 15.0) -> Path:
    """Write frames (each (h, w, 3) uint8, all one size) as a looping animation.

    The suffix picks the format: ``.png``/``.apng`` animated PNG, ``.gif`` GIF
    (each frame quantised to 256 colours).
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in ANIMATION_SUFFIXES:
        raise ValueError(f"an animation is written as {', '.join(ANIMATION_SUFFIXES)}, not {path.name!r}")
    images = [Image.fromarray(_checked(frame)) for frame in frames]
    if not images:
        raise ValueError("an animation needs at least one frame")
    if len({image.size for image in images}) > 1:
        raise ValueError("every frame of an animation must have the same size")
    if not fps > 0:
        raise ValueError(f"fps must be positive, got {fps!r}")
    duration = max(int(round(1000.0 / fps)), 10)      # milliseconds; GIF counts in hundredths
    images[0].save(path, format="GIF" if suffix == ".gif" else "PNG", save_all=True,
                   append_images=images[1:], duration=duration, loop=0)
    return path


def contact_sheet(frames, columns: int | None = None, gap: int = 4, labels=None,
                  background=(255, 255, 255)) -> np.ndarray:
    """Frames (each (h, w, 3) uint8, all one size) in a grid, row by row.

    Args:
        columns: frames per row; default about the square root of their number.
        gap: pixels between frames and round the sheet.
        labels: optional text per frame, written in its top-left corner.

    Returns:
        (rows * (h + gap) + gap, columns * (w + gap) + gap, 3) uint8 image.
    """
    frames = [_checked(frame)[..., :3] for frame in frames]
    if not frames:
        raise ValueError("a contact sheet needs at least one frame")
    h, w = frames[0].shape[:2]
    if any(frame.shape[:2] != (h, w) for frame in frames):
        raise ValueError("every frame of a contact sheet must have the same size")
    columns = columns or math.ceil(math.sqrt(len(frames)))
    rows = math.ceil(len(frames) / columns)
    sheet = np.empty((rows * (h + gap) + gap, columns * (w + gap) + gap, 3), np.uint8)
    sheet[:] = background
    for i, frame in enumerate(frames):
        y, x = gap + (i // columns) * (h + gap), gap + (i % columns) * (w + gap)
        sheet[y:y + h, x:x + w] = frame
    if labels is not None:
        image = Image.fromarray(sheet)
        draw = ImageDraw.Draw(image)
        for i, text in enumerate(labels):
            y, x = gap + (i // columns) * (h + gap), gap + (i % columns) * (w + gap)
            draw.text((x + 3, y + 2), str(text), fill=(255, 255, 255), stroke_width=2, stroke_fill=(0, 0, 0))
        sheet = np.asarray(image)
    return sheet


def _checked(image) -> np.ndarray:
    image = np.asarray(image)
    if image.dtype != np.uint8 or image.ndim != 3 or image.shape[2] not in (3, 4):
        raise ValueError(f"an image is (h, w, 3 or 4) uint8, got {image.dtype} {image.shape}")
    return np.ascontiguousarray(image)
