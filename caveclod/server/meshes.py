"""The meshes a server serves: each ``.cvc`` opened once and shared by every session.

Opening a mesh memory-maps its arrays (``caveclod.load``) and checks its
header and structure (:mod:`caveclod.meshcheck`: one pass over the index
arrays, about 70 ms per million triangles), so a server with gigabytes of
meshes starts in seconds. What needs another pass over an array (bounds,
the vertex payload's CRC-32) is computed on the first request that needs it
and kept.

A damaged file given to ``caveclod serve`` is refused at start, one line
naming it, exit status 2, even beside good ones: a server that silently
served fewer meshes than it was given would be found out only by clients.
Damage the check at start cannot see shows while a camera refines
(:class:`caveclod.errors.MeshDamagedError`): that session ends with
DATA_LOSS, the mesh is marked damaged and new Opens of it are refused with
DATA_LOSS, and the server goes on serving its other meshes and sessions.
"""

from __future__ import annotations

import os
import threading
import time
from functools import cached_property
from pathlib import Path

import numpy as np

from .. import opstream, wire
from . import logs
from ..v1 import caveclod_pb2 as pb


class ServedMesh:
    """One static mesh under its file stem (``terrain.cvc`` -> ``terrain``).

    Attributes:
        name: the name clients open it by.
        mesh: the :class:`caveclod.StaticMesh` (memory-mapped, read-only).
    """

    def __init__(self, name: str, mesh):
        self.name = name
        self.mesh = mesh
        self._lock = threading.Lock()
        self._crc: int | None = None
        self._crc_lock = threading.Lock()
        self._info: pb.MeshInfo | None = None
        self._packed: dict = {}             # (position_bits, morph) -> (Packed, VertexPacking, VertexFormat)
        self._packing: dict = {}            # (position_bits, morph) -> the lock held while it is packed
        self.stored: set = set()            # (position_bits, morph) of the variants taken from the file
        self._op_links = None
        self._links_lock = threading.Lock()

    @cached_property
    def blocks(self) -> list[wire.VertexBlock]:
        """The planar vertex payload's blocks (views of the mapped arrays)."""
        m = self.mesh
        return wire.vertex_blocks(m.vertex_positions, m.vertex_normals, m.vertex_uvs, m.vertex_colors)

    @cached_property
    def vertex_format(self) -> pb.VertexFormat:
        return wire.vertex_format(self.blocks)

    @cached_property
    def base_vertices(self) -> int:
        """Vertices the base mesh uses: the fewest slots a cache-mode session needs."""
        from ..refine.activevertices import ActiveVertices
        return ActiveVertices(self.mesh.n_vertices, self.mesh.new_camera().triangles()).count

    @cached_property
    def vertex_keys(self):
        """(d,) float32 priority-queue keys of the ``lru_pq`` cache strategy (computed once, shared)."""
        from ..refine.vertexcache import vertex_keys
        return vertex_keys(self.mesh)

    @property
    def payload_crc32(self) -> int:
        """CRC-32 of the planar vertex payload (reads it once: ~15 ms per million vertices; under a
        lock of its own, so that Opens asking for ``info`` meanwhile do not wait)."""
        with self._crc_lock:
            if self._crc is None:
                self._crc = wire.payload_crc32(b.data for b in self.blocks)
            return self._crc

    @property
    def info(self) -> pb.MeshInfo:
        """MeshInfo with counts, materials, bounds and hashes (the bounds read every position once)."""
        with self._lock:
            if self._info is None:
                m = self.mesh
                self._info = wire.mesh_info(
                    self.name, faces=m.n_faces, vertices=m.n_vertices, positions=m.n_positions,
                    nodes=m.n_nodes, base_faces=len(m.arrays["base_faces"]), surface_group_ids=m.n_sgids,
                    materials=list(m.materials), bounds=m.bounds(), content_hash=m.content_hash,
                    vertex_buffer_hash=m.vertex_buffer_hash, origin=m.origin)
            return self._info

    def vertex_chunks(self, max_bytes: int = wire.MAX_CHUNK_BYTES):
        """The vertex payload as VertexChunk ServerMessages."""
        return wire.vertex_chunks(self.blocks, max_bytes)

    @cached_property
    def morph_targets(self) -> np.ndarray:
        """(d,) uint32 geomorph targets (:mod:`caveclod.refine.morphtargets`; computed once, shared)."""
        from ..refine.morphtargets import morph_targets
        return morph_targets(self.mesh)

    @property
    def op_links(self) -> tuple[np.ndarray, np.ndarray]:
        """(targets (d,) uint32, ranks (d,) uint8): what FRAME_ENCODING_OPS_LINKED
        streams name vertices by (:func:`caveclod.opstream.child_ranks`); 5 bytes a
        vertex, made once (by the server's warm-up, or the first Open that asks)."""
        with self._links_lock:               # concurrent Opens wait for one computation
            if self._op_links is None:
                targets = self.morph_targets
                self._op_links = targets, opstream.child_ranks(targets)
            return self._op_links

    def packed(self, position_bits: int, morph: bool = False) -> tuple:
        """(Packed, VertexPacking, VertexFormat) of the vertex buffer packed at ``position_bits``,
        with morph targets when ``morph`` (caveclod.vertexpack).

        Taken from the file where its build stored the variant
        (:func:`caveclod.vertexpack.attach_packed`: its CRC read once), else
        packed once and kept (a few bytes per vertex per variant): the
        server's default variant right after start (:meth:`LodServer._warm_up`),
        any other on the first Open that asks (about 0.5 s per million
        vertices, off the event loop). Opens that ask while it is packed
        wait for that one packing instead of starting their own.
        """
        from .. import vertexpack
        key = (position_bits, bool(morph))
        with self._lock:
            found = self._packed.get(key)
            if found is not None:
                return found
            packing = self._packing.setdefault(key, threading.Lock())
        with packing:
            with self._lock:
                found = self._packed.get(key)
            if found is None:
                m = self.mesh
                packed = self._stored_packed(position_bits, morph)
                if packed is None:
                    packed = vertexpack.pack(m.vertex_positions, m.vertex_normals, m.vertex_uvs, m.vertex_colors,
                                             position_bits, self.morph_targets if morph else None)
                found = (packed, vertexpack.to_message(packed, m.vertex_buffer_hash, m.content_hash),
                         vertexpack.vertex_format(self.blocks, morph))
                with self._lock:
                    self._packed[key] = found
        return found

    def _stored_packed(self, position_bits: int, morph: bool):
        """The file's stored variant (a vertexpack.Packed) or None; one the file holds damaged or
        stale is logged and left (the caller packs afresh)."""
        from .. import vertexpack
        try:
            packed = vertexpack.stored_packed(self.mesh, position_bits, morph)
        except ValueError as exc:
            logs.event("server.stored_packing_refused", mesh=self.name, position_bits=position_bits, morph=morph,
                       reason=str(exc), what_to_do=f"packing it now; 'caveclod pack {self.mesh.path}' stores it again")
            return None
        if packed is not None:
            self.stored.add((position_bits, bool(morph)))
        return packed

    def packed_chunks(self, position_bits: int, morph: bool = False, max_bytes: int = wire.MAX_CHUNK_BYTES):
        """The packed vertex buffer as VertexChunk ServerMessages (``packed`` first)."""
        data = self.packed(position_bits, morph)[0].data
        return wire.vertex_chunks([wire.VertexBlock(0, np.frombuffer(data, np.uint8))], max_bytes)


class Catalogue:
    """{name: ServedMesh} of the files given to ``caveclod serve``.

    Raises ``caveclod.CaveclodError`` (one line) for an unreadable file or two
    files with the same stem.
    """

    def __init__(self, paths: list, checked_dir: str | None = None):
        from ..errors import InputError
        from ..meshcheck import check_mesh
        from ..staticmesh import load
        self.meshes: dict[str, ServedMesh] = {}
        checks = []
        for path in paths:
            name = Path(path).stem
            try:
                name.encode("utf-8")
            except UnicodeEncodeError:
                # A file name in another encoding (a Latin-1 archive unpacked here): protobuf
                # could not send the name, and every ListMeshes failed, for every mesh.
                raise InputError(f"the mesh file name {os.fsencode(path)!r} is not UTF-8, so no client could "
                                 "name it; rename the file (meshes are served by file stem)") from None
            if name in self.meshes:
                raise InputError(f"two meshes named {name!r} ({self.meshes[name].mesh.path} and {path}); "
                                 "rename one file: meshes are served by file stem")
            t0 = time.perf_counter()
            mesh = load(path, check=False)
            read = check_mesh(mesh, checked_dir)
            checks.append(dict(mesh=name, faces=mesh.n_faces, seconds=round(time.perf_counter() - t0, 3),
                               how="read" if read else "unchanged since checked"))
            self.meshes[name] = ServedMesh(name, mesh)
        if not self.meshes:
            raise InputError("no mesh to serve; give at least one .cvc file (build one with 'caveclod build')")
        for fields in checks:             # once every mesh passed: a refusal stays the one line it is
            logs.event("mesh.checked", **fields)

    def get(self, name: str) -> ServedMesh | None:
        return self.meshes.get(name)

    def names(self) -> list[str]:
        return sorted(self.meshes)

    def listing(self) -> pb.ListMeshesResponse:
        return pb.ListMeshesResponse(meshes=[self.meshes[n].info for n in self.names()])
