"""The repair corpus: scanned meshes rendered from sparse and novel views, the coarse stage run on the sparse
views, and (coarse render, true render, true alpha) pairs at the novel views (issue 34).

``assets`` finds the objects in the LIBERO-PRO asset tree, ``geometry`` reads meshes and compares shapes,
``exclusion`` keeps the reserved objects and their recoloured / rescaled variants out, ``views`` draws the
cameras and lighting of one object, ``pairs`` turns a rendered object plus its coarse model into pairs.
The driver is ``benchmarks/prior/repair_corpus.py``. This folder is not part of the installed package: the
scripts beside it import it as ``corpus`` (their own folder is first on ``sys.path`` when they run).
"""
