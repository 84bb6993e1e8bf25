"""Per-camera refinement over a shared static mesh (Hoppe 1997; Kram & Shaw 3.4-3.6).

``view.View`` (a pose and the criteria), ``camera.CameraState`` (one
camera's active nodes and faces, refined by ``caveclod.kernels.refine``),
``reference`` (the same rules in slow plain Python, for tests) and
``validate`` (invariant checks).
"""
