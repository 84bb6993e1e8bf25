"""The offline build: any mesh or heightfield -> a static CAVECLOD hierarchy.

One module a step (see :mod:`caveclod.builder.hierarchy` for the pipeline):
``meshfile`` and ``terrain`` read inputs into a ``source.SourceMesh``;
``weld`` merges near positions; ``normals``, ``topology`` and ``surfaces``
prepare it; ``hierarchy`` runs the collapses (``caveclod.kernels.simplify``)
and lays out the static arrays of ``caveclod.staticmesh``.
"""
