"""Quantized and meshopt-compressed glTF: integer vertex attributes, texture transforms and
``EXT_meshopt_compression``, applied before trimesh reads.

gltfpack, the usual glTF optimizer, quantizes by default
(``KHR_mesh_quantization``): positions become integers scaled back by the
node's transform, normals and texture coordinates *normalized* integers
(an int8 of 127 is 1.0, a uint16 of 65535 is 1.0), and each texture's
coordinates are moved back into place by ``KHR_texture_transform`` on the
material. trimesh reads the integers as they are and ignores the
transform: positions come out right (the node's transform applies), but a
quantized file's texture coordinates came out as 0 to 65535 instead of
their true values, silently.

:func:`dequantized_gltf` rewrites such a file in memory before trimesh
sees it: each normalized attribute a primitive uses becomes float32 per
the glTF specification (``max(c / (2**(b-1) - 1), -1)`` signed, ``c /
(2**b - 1)`` unsigned), and the texture coordinates that a material's base
colour texture reads through a ``KHR_texture_transform`` take the
transform (offset, rotation, scale), baked per primitive. gltfpack's
``-c`` also compresses the buffer views (``EXT_meshopt_compression``:
meshoptimizer's vertex and index codecs, and its octahedral, quaternion
and exponential filters), which trimesh cannot read at all; they are
decoded first, with the ``meshoptimizer`` package where it is installed
(``make`` installs it; :mod:`.gltfcodecs` refuses such a file, saying so,
where it is not), every size checked before the decoder writes. The
result is one GLB with every buffer in its binary chunk; a file that
needs none of this is read as it is (its buffers are not read here: the
JSON alone says whether anything needs rewriting).
"""

from __future__ import annotations

import base64
import importlib.util
import json
import math
import os
import struct
from pathlib import Path
from urllib.parse import unquote

import numpy as np

from ..errors import InputError
from .gltfcodecs import DECODABLE_WITH, GLB_MAGIC, JSON_CHUNK
from .source import FLOAT32_MAX

_BIN_CHUNK = 0x004E4942
_COMPONENTS = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4}
_DTYPES = {5120: np.int8, 5121: np.uint8, 5122: np.int16, 5123: np.uint16, 5125: np.uint32, 5126: np.float32}
_FLOAT = 5126
_DEQUANTIZED = ("POSITION", "NORMAL", "TANGENT", "TEXCOORD_", "COLOR_")
MAX_DECODED_BYTES = 1 << 31         # largest bufferView decoded (a damaged count must not allocate more)


def dequantized_gltf(path: Path, file_type: str) -> bytes | None:
    """``path`` as GLB bytes with its normalized attributes and texture transforms applied, and
    the primitives trimesh would leave out made readable (:func:`_primitives_to_rewrite`), or
    None when it has none of them (or is not glTF, or does not parse: trimesh then reads it and
    reports)."""
    if file_type not in ("glb", "gltf"):
        return None
    try:
        tree, binary = _read_json(path, file_type)
    except Exception:       # any damage: left to trimesh, whose error the loader turns into one line
        return None
    try:
        todo = _attributes_to_rewrite(tree) + _primitives_to_rewrite(tree)
        if not todo and not _compressed_views(tree):
            return None                          # nothing to rewrite: the buffers need not be read
    except Exception as exc:
        raise _undecodable(path, exc) from None
    try:
        buffers = _read_buffers(path, tree, binary)
    except Exception:
        return None
    try:
        out = bytearray()
        if not _rewrite(tree, buffers, out, todo):
            return None
    except InputError as exc:
        raise InputError(f"{path}: {exc}") from None
    except Exception as exc:    # a damaged tree, whatever shape its damage takes
        raise _undecodable(path, exc) from None
    return glb_bytes(tree, bytes(out))


def _undecodable(path: Path, exc: Exception) -> InputError:
    return InputError(f"{path}: its compressed or quantized glTF buffers do not decode ({type(exc).__name__}: "
                      f"{' '.join(str(exc).split())[:200]}); the file is damaged: export it again")


# ------------------------------------------------------------------ reading and writing


def _read_json(path: Path, file_type: str) -> tuple[dict, tuple[int, int] | None]:
    """(JSON tree, (offset, length) of a GLB's binary chunk, or None): the chunks' headers and the
    JSON read, the binary chunk only found."""
    binary = None
    if file_type == "glb":
        with open(path, "rb") as f:
            size = os.fstat(f.fileno()).st_size
            magic, _, _ = struct.unpack("<III", f.read(12))
            if magic != GLB_MAGIC:
                raise ValueError("not a GLB")
            at, text = 12, None
            while at + 8 <= size:
                f.seek(at)
                length, kind = struct.unpack("<II", f.read(8))
                if kind == JSON_CHUNK and text is None:
                    text = f.read(length)
                elif kind == _BIN_CHUNK and binary is None:
                    binary = (at + 8, min(length, size - at - 8))
                at += 8 + length + (-length % 4)
        tree = json.loads(text)
    else:
        tree = json.loads(path.read_bytes())
    if not isinstance(tree, dict):
        raise ValueError("not a glTF object")
    return tree, binary


def _read_buffers(path: Path, tree: dict, binary: tuple[int, int] | None) -> list:
    """[bytes of each of the tree's buffers, or None where it cannot be had]: a GLB's binary
    chunk at ``binary`` (offset, length), data URIs, files beside ``path``."""
    buffers = []
    for i, b in enumerate(tree.get("buffers", [])):
        uri = b.get("uri")
        if uri is None:
            if i == 0 and binary is not None:
                with open(path, "rb") as f:
                    f.seek(binary[0])
                    buffers.append(f.read(binary[1]))
            else:
                buffers.append(None)
        elif uri.startswith("data:"):
            buffers.append(base64.b64decode(uri.split(",", 1)[1]))
        else:
            target = (path.parent / unquote(uri)).resolve()      # glTF URIs are percent-encoded
            buffers.append(target.read_bytes() if target.is_file() else None)
    return buffers


def glb_bytes(tree: dict, binary: bytes) -> bytes:
    """A GLB of a glTF ``tree`` and its binary chunk (padded as the format wants)."""
    text = json.dumps(tree, separators=(",", ":")).encode()
    text += b" " * (-len(text) % 4)
    binary += b"\0" * (-len(binary) % 4)
    body = struct.pack("<II", len(text), JSON_CHUNK) + text + struct.pack("<II", len(binary), _BIN_CHUNK) + binary
    return struct.pack("<III", GLB_MAGIC, 2, 12 + len(body)) + body


# ------------------------------------------------------------------ the rewrite


def _compressed_views(tree: dict) -> list[int]:
    """The indices of the bufferViews compressed with EXT_meshopt_compression."""
    views = tree.get("bufferViews", [])
    return [i for i, v in enumerate(views) if "EXT_meshopt_compression" in v.get("extensions", {})]


def _attributes_to_rewrite(tree: dict) -> list[tuple]:
    """[(primitive, attribute name, accessor index, transform or None)]: the normalized attributes
    to dequantize and the texture coordinates a base colour texture's transform moves."""
    accessors, todo = tree.get("accessors", []), []
    for mesh in tree.get("meshes", []):
        for prim in mesh.get("primitives", []):
            transform, tex_coord = _base_colour_transform(tree, prim)
            for name, index in prim.get("attributes", {}).items():
                acc = accessors[index]
                quantized = acc.get("normalized") and name.startswith(_DEQUANTIZED)
                moved = transform is not None and name == f"TEXCOORD_{tex_coord}"
                if (quantized or moved) and "bufferView" in acc and "sparse" not in acc:
                    todo.append((prim, name, index, transform if moved else None))
    return todo


def _rewrite(tree: dict, buffers: list, out: bytearray, todo: list) -> bool:
    """Rewrite ``tree`` in place to one binary buffer (written to ``out``), the attributes ``todo``
    (:func:`_attributes_to_rewrite`) among it; False if nothing needed it."""
    accessors, views = tree.get("accessors", []), tree.get("bufferViews", [])
    compressed = _compressed_views(tree)
    if compressed and importlib.util.find_spec("meshoptimizer") is None:
        # Without the decoder, views whose own buffer holds the fallback data (extensionsUsed
        # only) are read as they are; a view without it cannot be.
        if any(buffers[views[i]["buffer"]] is None for i in compressed):
            package, install = DECODABLE_WITH["EXT_meshopt_compression"]
            raise InputError(f"its geometry is compressed with EXT_meshopt_compression, which needs the "
                             f"{package} package: {install}")
        compressed = []
    decoded = {i: _decompressed(views[i], buffers) for i in compressed}
    if not todo and not decoded:
        return False
    # One buffer: the file's buffers one after another, the decompressed views, then the new arrays.
    starts = []
    for b in buffers:
        starts.append(len(out))
        if b is not None:
            out += b + b"\0" * (-len(b) % 4)
    for i, view in enumerate(views):
        if i in decoded:
            view["byteOffset"], view["byteLength"] = len(out), len(decoded[i])
            out += decoded[i] + b"\0" * (-len(decoded[i]) % 4)
            del view["extensions"]["EXT_meshopt_compression"]
        elif buffers[view["buffer"]] is None:
            raise ValueError(f"buffer {view['buffer']} of a bufferView could not be read")
        else:
            view["byteOffset"] = starts[view["buffer"]] + view.get("byteOffset", 0)
        view["buffer"] = 0
    made = {}
    for prim, name, index, transform in todo:
        if name in (_FAN, _BARE):
            _rewrite_primitive(tree, accessors, views, out, prim, name)
            continue
        key = (index, transform)
        if key not in made:
            values = _values(accessors[index], views, out)
            if transform is not None:
                values = _transformed(values, transform)
            made[key] = _append(tree, accessors, views, out, accessors[index], values)
        prim["attributes"][name] = made[key]
    tree["buffers"] = [{"byteLength": len(out)}]
    _drop_extension(tree, "KHR_mesh_quantization")
    _drop_extension(tree, "EXT_meshopt_compression")
    if any(t is not None for _, _, _, t in todo):
        for material in tree.get("materials", []):
            info = material.get("pbrMetallicRoughness", {}).get("baseColorTexture", {})
            info.get("extensions", {}).pop("KHR_texture_transform", None)
    return True


_FAN, _BARE = " fan", " no material"        # todo entries of primitives (no attribute is named so)
_TRIANGLE_FAN = 6


def _primitives_to_rewrite(tree: dict) -> list[tuple]:
    """[(primitive, _FAN or _BARE, None, None)]: primitives trimesh would leave out, whole or in
    part, without a word. A triangle fan (mode 6) it skips (a file of fans alone read as "no
    geometry"); texture coordinates on a primitive with no material it drops (read as (0, 0)).
    Each becomes what trimesh reads: a triangle list, a plain material of its own."""
    todo = []
    for mesh in tree.get("meshes", []):
        for prim in mesh.get("primitives", []):
            if prim.get("mode") == _TRIANGLE_FAN:
                todo.append((prim, _FAN, None, None))
            if "material" not in prim and any(n.startswith("TEXCOORD_") for n in prim.get("attributes", {})):
                todo.append((prim, _BARE, None, None))
    return todo


def _rewrite_primitive(tree: dict, accessors: list, views: list, out: bytearray, prim: dict, what: str) -> None:
    """A fan's triangles as a list (uint32 indices appended to ``out``), or a material of its own
    (unnamed, white: the glTF default) for a primitive with texture coordinates and none."""
    if what == _BARE:
        tree.setdefault("materials", []).append({})
        prim["material"] = len(tree["materials"]) - 1
        return
    if "indices" in prim:
        order = _values(accessors[prim["indices"]], views, out)[:, 0].astype(np.int64)
    else:
        order = np.arange(int(accessors[prim["attributes"]["POSITION"]]["count"]), dtype=np.int64)
    k = np.arange(1, max(len(order) - 1, 1))
    triangles = np.stack([np.full(len(k), order[0] if len(order) else 0), order[k], order[k + 1]], axis=1) \
        if len(order) >= 3 else np.zeros((0, 3), np.int64)
    indices = np.ascontiguousarray(triangles.reshape(-1), "<u4")
    out += b"\0" * (-len(out) % 4)
    views.append({"buffer": 0, "byteOffset": len(out), "byteLength": indices.nbytes})
    out += indices.tobytes()
    tree["bufferViews"] = views
    accessors.append({"bufferView": len(views) - 1, "componentType": 5125, "type": "SCALAR",
                      "count": int(len(indices))})
    prim["indices"], prim["mode"] = len(accessors) - 1, 4


MESHOPT_FILTERS = {"OCTAHEDRAL": ("decode_filter_oct", (4, 8)), "QUATERNION": ("decode_filter_quat", (8,)),
                   "EXPONENTIAL": ("decode_filter_exp", None)}
"""EXT_meshopt_compression's filters: the meshoptimizer function and the strides it takes (None:
any multiple of 4)."""


def _decompressed(view: dict, buffers: list) -> bytes:
    """The ``count * byteStride`` bytes an EXT_meshopt_compression bufferView holds, decoded."""
    import meshoptimizer

    ext = view["extensions"]["EXT_meshopt_compression"]
    count, stride, mode = int(ext["count"]), int(ext["byteStride"]), ext["mode"]
    source = buffers[ext["buffer"]]
    start = int(ext.get("byteOffset", 0))
    data = None if source is None else source[start:start + int(ext["byteLength"])]
    if data is None or start < 0 or len(data) != int(ext["byteLength"]):
        raise ValueError("a compressed bufferView reaches past its buffer")
    if not 0 < count <= MAX_DECODED_BYTES // max(stride, 1):
        raise ValueError(f"a compressed bufferView of {count} items of {stride} bytes")
    if mode == "ATTRIBUTES":
        if not (0 < stride <= 256 and stride % 4 == 0):
            raise ValueError(f"a compressed attribute stride of {stride} bytes (a multiple of 4 up to 256)")
        # dtype None: the wrapper allocates count x stride bytes (as float32 words), what the decoder writes
        values = meshoptimizer.decode_vertex_buffer(count, stride, data)
        name = ext.get("filter", "NONE")
        if name != "NONE":
            function, strides = MESHOPT_FILTERS[name]
            if (strides is not None and stride not in strides) or values.nbytes != count * stride:
                raise ValueError(f"the {name} filter on items of {stride} bytes")
            values = getattr(meshoptimizer, function)(values, count, stride)
        raw = values.tobytes()
    elif mode in ("TRIANGLES", "INDICES"):
        if stride not in (2, 4) or (mode == "TRIANGLES" and count % 3):
            raise ValueError(f"compressed indices of {stride} bytes, {count} of them")
        decode = meshoptimizer.decode_index_buffer if mode == "TRIANGLES" else meshoptimizer.decode_index_sequence
        # The wrapper allocates 4 bytes an index whatever their size; 2-byte ones fill its first half.
        raw = decode(count, stride, data).tobytes()
    else:
        raise ValueError(f"compression mode {mode!r}")
    if len(raw) < count * stride:
        raise ValueError("a compressed bufferView decoded short")
    return raw[:count * stride]


def _base_colour_transform(tree: dict, prim: dict) -> tuple[tuple | None, int]:
    """(the KHR_texture_transform of the primitive's base colour texture as (ox, oy, rotation, sx, sy),
    or None; the texture coordinate set it reads)."""
    materials = tree.get("materials", [])
    m = prim.get("material")
    if m is None or not 0 <= m < len(materials):
        return None, 0
    info = materials[m].get("pbrMetallicRoughness", {}).get("baseColorTexture")
    if not isinstance(info, dict):
        return None, 0
    t = info.get("extensions", {}).get("KHR_texture_transform")
    if not isinstance(t, dict):
        return None, int(info.get("texCoord", 0))
    offset, scale = t.get("offset", [0.0, 0.0]), t.get("scale", [1.0, 1.0])
    numbers = (float(offset[0]), float(offset[1]), float(t.get("rotation", 0.0)), float(scale[0]), float(scale[1]))
    if not all(math.isfinite(v) for v in numbers):
        raise ValueError("a KHR_texture_transform holds a non-finite number")
    return numbers, int(t.get("texCoord", info.get("texCoord", 0)))


def _values(acc: dict, views: list, data: bytearray) -> np.ndarray:
    """(count, k) float64 values of an accessor, normalized integers mapped per the glTF spec."""
    dtype = np.dtype(_DTYPES[acc["componentType"]]).newbyteorder("<")
    k, count = _COMPONENTS[acc["type"]], int(acc["count"])
    view = views[acc["bufferView"]]
    stride = view.get("byteStride") or k * dtype.itemsize
    if not isinstance(stride, int) or stride < k * dtype.itemsize:
        raise ValueError(f"a bufferView's byteStride {stride!r} is shorter than its items")
    start = view["byteOffset"] + acc.get("byteOffset", 0)
    end = start + (count - 1) * stride + k * dtype.itemsize if count else start
    if count < 0 or end > view["byteOffset"] + view["byteLength"] or end > len(data):
        raise ValueError(f"an accessor of {count} items reaches past its bufferView")
    # A copy of the bytes: a view would pin ``data``, which grows as accessors are appended.
    raw = np.ndarray((count, k), dtype, buffer=bytes(data[start:end]), strides=(stride, dtype.itemsize)) if count \
        else np.zeros((0, k), dtype)
    values = raw.astype(np.float64)
    if acc.get("normalized") and dtype.kind in "iu":
        top = float(np.iinfo(dtype).max)
        values = np.maximum(values / top, -1.0)
    return values


def _transformed(uv: np.ndarray, t: tuple) -> np.ndarray:
    """KHR_texture_transform's ``translation * rotation * scale`` applied to (n, 2) ``uv``."""
    ox, oy, r, sx, sy = t
    c, s = math.cos(r), math.sin(r)
    u, v = uv[:, 0] * sx, uv[:, 1] * sy
    return np.stack([c * u + s * v + ox, -s * u + c * v + oy], axis=1)


def _append(tree: dict, accessors: list, views: list, out: bytearray, like: dict, values: np.ndarray) -> int:
    """A new float32 accessor (and bufferView) of ``values`` in ``out``, shaped like ``like``; its index."""
    if not (np.abs(values) <= FLOAT32_MAX).all():
        raise ValueError("an attribute's texture transform takes it beyond float32 (or to NaN)")
    values32 = np.ascontiguousarray(values, "<f4")
    out += b"\0" * (-len(out) % 4)
    views.append({"buffer": 0, "byteOffset": len(out), "byteLength": values32.nbytes})
    out += values32.tobytes()
    acc = {key: v for key, v in like.items() if key not in ("normalized", "byteOffset", "min", "max", "sparse")}
    acc.update(bufferView=len(views) - 1, componentType=_FLOAT)
    if len(values32):
        acc.update(min=values32.min(axis=0).tolist(), max=values32.max(axis=0).tolist())
    tree["bufferViews"] = views
    accessors.append(acc)
    return len(accessors) - 1


def _drop_extension(tree: dict, name: str) -> None:
    for key in ("extensionsUsed", "extensionsRequired"):
        if name in tree.get(key, []):
            tree[key] = [n for n in tree[key] if n != name]
            if not tree[key]:
                del tree[key]
