"""go_core: the GaussianObject library, grouped by stage (docs/architecture.md has the map).

The top level holds only the types every stage shares: ``camera``, ``gaussians``, ``sh``, ``ply``,
``config`` (typed settings), ``errors``, ``seeding`` and the artifact catalogue (``artifact_files``,
``artifacts``). Stages: ``scene`` (input and masks), ``poses``, ``coarse`` (hull and 3DGS training),
``repair`` with its models ``compact`` and ``diffusion``, ``render``, ``metrics``; shared services:
``io``, ``features``, ``kernels``. It never imports the runner (``go_pipeline``) or the step functions
(tests/test_import_graph.py).
"""

__version__ = "0.1.0"
