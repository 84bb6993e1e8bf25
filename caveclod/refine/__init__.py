"""Per-camera refinement over a shared static mesh (Hoppe 1997; Kram & Shaw 3.4-3.6).

``view.View`` (a pose and the criteria), ``camera.CameraState`` (one
camera's active nodes and faces, refined by ``caveclod.kernels.refine``),
``reference`` (the same rules in slow plain Python, for tests) and
``validate`` (invariant checks).

Cache mode (Lario, Pajarola & Tirado's Cached Geometry Manager): a client
holds N vertex slots instead of the vertex buffer. ``activevertices``
(which vertices each delta adds and removes), ``vertexcache`` (the slots
and the FA / LRU / LRU+PQ strategies, kernels in
``caveclod.kernels.vertexcache``) and ``cachedcamera`` (a CameraState fitted
to its cache, with deltas in slot numbers).
"""
