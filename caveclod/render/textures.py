"""Textures of the materials: the mesh's own images, or generated ones.

Terrains tile each material's UVs at the material's own scale (water, grass,
rock and snow, see :mod:`caveclod.builder.landcover`), so their generated
textures are tileable: a base colour with procedural detail (periodic value
noise, ripples, cracks, speckles) whose repeats show where UVs tile. A name
without a palette gets a neutral grey checker, tinted a little by the name so
that neighbouring materials stay apart.
"""

from __future__ import annotations

import zlib

import numpy as np

SIZE = 128
"""Texels per side of a generated texture (a power of two: mipmaps, repeat)."""


def material_texture(name: str, size: int = SIZE) -> np.ndarray:
    """(size, size, 3) uint8 tileable texture for a material called ``name``."""
    make = PALETTE.get(name.lower(), _neutral)
    rng = np.random.default_rng(zlib.crc32(name.lower().encode()))
    return np.clip(make(rng, size, name) * 255.0 + 0.5, 0, 255).astype(np.uint8)


def check_texture(image) -> np.ndarray:
    """(h, w, 3 | 4) uint8 image as given, or ``ValueError``."""
    image = np.asarray(image)
    if image.dtype != np.uint8 or image.ndim != 3 or image.shape[2] not in (3, 4) or min(image.shape[:2]) < 1:
        raise ValueError(f"a texture must be an (h, w, 3 or 4) uint8 image, got {image.dtype} {image.shape}")
    return np.ascontiguousarray(image)


def periodic_noise(rng: np.random.Generator, size: int, cells: int) -> np.ndarray:
    """(size, size) float64 value noise in [0, 1] that tiles: a ``cells`` x
    ``cells`` lattice of random values, wrapped, with smoothstep interpolation."""
    lattice = rng.random((cells, cells))
    t = np.arange(size) * cells / size
    i = t.astype(np.int64)
    f = t - i
    f = f * f * (3.0 - 2.0 * f)
    j = (i + 1) % cells
    rows = lattice[i][:, i] * (1 - f)[None, :] + lattice[i][:, j] * f[None, :]
    rows_next = lattice[j][:, i] * (1 - f)[None, :] + lattice[j][:, j] * f[None, :]
    return rows * (1 - f)[:, None] + rows_next * f[:, None]


def fractal_noise(rng: np.random.Generator, size: int, octaves: int = 4, cells: int = 4) -> np.ndarray:
    """(size, size) tileable noise in [0, 1]: octaves of :func:`periodic_noise`, halving amplitude."""
    total = np.zeros((size, size))
    weight = 0.0
    for octave in range(octaves):
        amplitude = 0.5 ** octave
        total += amplitude * periodic_noise(rng, size, min(cells << octave, size))
        weight += amplitude
    return total / weight


def _shade(base, noise: np.ndarray, depth: float) -> np.ndarray:
    """(size, size, 3): ``base`` RGB in [0, 1] brightened/darkened by ``depth`` * (noise - 0.5)."""
    return np.asarray(base)[None, None, :] * (1.0 + depth * (noise[..., None] - 0.5) * 2.0)


def _water(rng, size, name):
    y, x = np.mgrid[0:size, 0:size] * (2.0 * np.pi / size)
    ripples = 0.5 + 0.25 * np.sin(4 * x + 2 * np.sin(2 * y)) + 0.25 * np.sin(6 * y + 3 * np.sin(x))
    return _shade((0.16, 0.34, 0.58), 0.6 * ripples + 0.4 * fractal_noise(rng, size), 0.25)


def _grass(rng, size, name):
    blades = rng.random((size, size)) ** 4          # sparse bright blades
    return _shade((0.30, 0.50, 0.18), 0.7 * fractal_noise(rng, size, 5) + 0.3 * blades, 0.45)


def _rock(rng, size, name):
    noise = fractal_noise(rng, size, 5, cells=2)
    # Cracks: where a second noise field crosses its middle value.
    cracks = np.abs(fractal_noise(rng, size, 3, cells=4) - 0.5) < 0.02
    rock = _shade((0.47, 0.44, 0.41), noise, 0.6)
    rock[cracks] *= 0.45
    return rock


def _snow(rng, size, name):
    sparkle = (rng.random((size, size)) > 0.985).astype(float)
    return np.minimum(_shade((0.90, 0.93, 0.97), fractal_noise(rng, size, 4) + 0.4 * sparkle, 0.12), 1.0)


def _neutral(rng, size, name):
    """Light grey checker (8 x 8 squares) tinted by a hue from the name, with faint noise."""
    y, x = np.mgrid[0:size, 0:size] * 8 // size
    checker = np.where((x + y) % 2 == 0, 0.74, 0.62)
    hue = zlib.crc32(name.encode()) % 360 * np.pi / 180.0
    tint = 1.0 + 0.12 * np.cos(hue - np.array([0.0, 2.0944, 4.1888]))
    return checker[..., None] * tint[None, None, :] * (0.92 + 0.16 * fractal_noise(rng, size)[..., None])


PALETTE = {"water": _water, "grass": _grass, "rock": _rock, "snow": _snow}
"""Generated textures of the terrain classes, by material name."""
