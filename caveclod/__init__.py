"""caveclod: view-dependent continuous LOD for many cameras at once.

After Kram & Shaw, *Multiple Camera Considerations in a View-Dependent
Continuous LOD Algorithm* (CAVECLOD), and Hoppe, *View-Dependent Refinement
of Progressive Meshes* (1997).

    mesh = caveclod.build("default", size=256)     # or a mesh / heightfield path
    mesh.save("terrain.cvc")
    mesh = caveclod.load("terrain.cvc")             # memory-mapped
"""

from .api import build, load
from .errors import CaveclodError, FileFormatError, InputError
from .staticmesh import StaticMesh

__all__ = ["build", "load", "StaticMesh", "CaveclodError", "InputError", "FileFormatError"]
__version__ = "0.1.0"
