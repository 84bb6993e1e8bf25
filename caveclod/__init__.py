"""caveclod: view-dependent continuous LOD for many cameras at once.

After Kram & Shaw, *Multiple Camera Considerations in a View-Dependent
Continuous LOD Algorithm* (CAVECLOD), and Hoppe, *View-Dependent Refinement
of Progressive Meshes* (1997).

    mesh = caveclod.build("default", size=256)     # or a mesh / heightfield path
    mesh.save("terrain.cvc")
    mesh = caveclod.load("terrain.cvc")             # memory-mapped
    cam = mesh.new_camera()                         # one per camera, all sharing mesh
    delta = cam.update(caveclod.View(eye=(5000, -2000, 1500), target=(5000, 5000, 300)))
    cam.triangles()                                 # {material: (k, 3) uint32}

The package's parts:

* ``caveclod.builder``: the offline build (mesh files, heightfields, normals,
  topology, surface groups, the vertex hierarchy);
* ``caveclod.refine``: per-camera refinement (View, CameraState, the slow
  reference, invariant checks);
* ``caveclod.kernels``: the numba kernels both use;
* ``caveclod.staticmesh``: the ``.cvc`` file both phases share;
* ``caveclod.server``: the gRPC LOD service (``caveclod serve``);
* ``caveclod.client``: the thin client and the load tester;
* ``caveclod.wire`` and ``caveclod.v1``: the caveclod.v1 codec and its
  generated stubs, shared by both.

Names below are imported on first use, so that ``import caveclod.client``
(the thin client, which needs only numpy, grpcio and protobuf) does not pull
in numba or trimesh.
"""

from importlib import import_module

from .errors import CaveclodError, FileFormatError, InputError

_LAZY = {
    "build": ".api",
    "build_tiles": ".api",
    "load": ".api",
    "StaticMesh": ".staticmesh",
    "View": ".refine.view",
    "CameraState": ".refine.camera",
    "Delta": ".refine.camera",
    "SurfaceDelta": ".refine.camera",
    "CachedCamera": ".refine.cachedcamera",
}

__all__ = ["build", "build_tiles", "load", "StaticMesh", "View", "CameraState", "Delta", "SurfaceDelta", "CachedCamera",
           "CaveclodError", "InputError", "FileFormatError"]
__version__ = "0.1.0"


def __getattr__(name):
    if name in _LAZY:
        value = getattr(import_module(_LAZY[name], __name__), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'caveclod' has no attribute {name!r}")


def __dir__():
    return sorted(set(globals()) | set(_LAZY))
