"""Compressed glTF geometry: what trimesh decodes, and a clear refusal for what it does not.

Web and photogrammetry pipelines often ship GLB/glTF with the geometry
compressed. trimesh decodes ``KHR_draco_mesh_compression`` through the
DracoPy package (Google's Draco, a dependency of ``caveclod[build]``);
``EXT_meshopt_compression`` (gltfpack's ``-c``) is decoded before trimesh
reads the file (:mod:`.gltfquant`) with the ``meshoptimizer`` package.
Without the package a file needs, trimesh logs that an extension "didn't
decode" and fills the geometry with zeros, which the build then refuses as
"every face is degenerate": true, but not what the user must change. So
the file's JSON is read first (:func:`refuse_undecodable`) and the
reader's log watched while it loads (:class:`UndecodedWatch`); either
names the extension and what to do.
"""

from __future__ import annotations

import importlib.util
import json
import logging
import struct
from pathlib import Path

from ..errors import InputError

CODECS = {
    "KHR_draco_mesh_compression": "Draco",
    "EXT_meshopt_compression": "meshoptimizer's codecs, gltfpack -c",
}
"""glTF extensions that compress geometry, by what they are called in messages."""

DECODABLE_WITH = {"KHR_draco_mesh_compression": ("DracoPy", "pip install DracoPy (caveclod[build] installs it)"),
                  "EXT_meshopt_compression": ("meshoptimizer", "pip install --pre meshoptimizer (make installs it)")}
"""Extensions decoded here (Draco by trimesh, meshopt by :mod:`.gltfquant`), the package each needs
and how to install it."""

GLB_MAGIC, JSON_CHUNK = 0x46546C67, 0x4E4F534A
"""A GLB's magic number and its JSON chunk's type."""
_MAX_JSON_BYTES = 64 << 20          # a glTF's JSON larger than this is read by trimesh, unchecked here


def required_extensions(path: Path, file_type: str) -> set[str]:
    """The ``extensionsRequired`` of a ``.glb``/``.gltf`` file (empty for other types, or where the
    JSON does not parse: trimesh then reports the damage)."""
    if file_type not in ("glb", "gltf"):
        return set()
    try:
        with open(path, "rb") as f:
            if file_type == "glb":
                header = f.read(20)
                if len(header) < 20:
                    return set()
                magic, _, _, length, kind = struct.unpack("<IIIII", header)
                if magic != GLB_MAGIC or kind != JSON_CHUNK or length > _MAX_JSON_BYTES:
                    return set()
                text = f.read(length)
            else:
                text = f.read(_MAX_JSON_BYTES + 1)
                if len(text) > _MAX_JSON_BYTES:
                    return set()
        tree = json.loads(text)
    except (OSError, ValueError, UnicodeDecodeError, RecursionError):
        return set()
    needed = tree.get("extensionsRequired") if isinstance(tree, dict) else None
    return {str(name) for name in needed} if isinstance(needed, list) else set()


def refuse_undecodable(path: Path, file_type: str) -> None:
    """InputError when ``path`` requires a geometry codec this installation cannot decode."""
    for name in sorted(required_extensions(path, file_type) & set(CODECS)):
        package, install = DECODABLE_WITH[name]
        if importlib.util.find_spec(package) is None:
            raise InputError(f"{path}: its geometry is compressed with {name} ({CODECS[name]}), which needs the "
                             f"{package} package: {install}; or export the file without that compression")


class UndecodedWatch(logging.Handler):
    """Collects trimesh's "extension didn't decode" warnings while a file loads, printing nothing.

    Use as a context manager around the read; :meth:`check` then raises
    InputError naming the extensions whose geometry stayed zeros.
    """

    LOGGER = "trimesh"

    def __init__(self) -> None:
        super().__init__(logging.WARNING)
        self.undecoded: list[str] = []
        self._saved: list = []

    def emit(self, record: logging.LogRecord) -> None:
        try:
            message = record.getMessage()
        except Exception:   # a record whose arguments do not format is not the one watched for
            return
        if "didn't decode" in message:
            self.undecoded.append(message.split("`")[1] if message.count("`") >= 2 else message)

    def __enter__(self) -> UndecodedWatch:
        # Records reach this handler only: the logger's level lets warnings through, and they stop here.
        for name in (self.LOGGER, self.LOGGER + ".util"):
            logger = logging.getLogger(name)
            self._saved.append((logger, logger.level, logger.propagate))
        util = logging.getLogger(self.LOGGER + ".util")
        util.setLevel(logging.WARNING)
        util.propagate = False
        util.addHandler(self)
        return self

    def __exit__(self, *exc) -> None:
        logging.getLogger(self.LOGGER + ".util").removeHandler(self)
        for logger, level, propagate in self._saved:
            logger.setLevel(level)
            logger.propagate = propagate

    def check(self, path: Path) -> None:
        if self.undecoded:
            names = ", ".join(sorted(set(self.undecoded)))
            raise InputError(f"{path}: its geometry is compressed with {names}, and decoding it failed (the "
                             "compressed data is damaged or of a version the decoder does not read); export the "
                             "file again, without that compression")
