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
"""

from .api import build, load
from .camera import CameraState, Delta, SurfaceDelta
from .errors import CaveclodError, FileFormatError, InputError
from .staticmesh import StaticMesh
from .view import View

__all__ = ["build", "load", "StaticMesh", "View", "CameraState", "Delta", "SurfaceDelta",
           "CaveclodError", "InputError", "FileFormatError"]
__version__ = "0.1.0"
