"""Gaussian repair (paper Sec. 3.4-3.5), independent of which repair model runs: leave-one-out runs
(``loo``) and 3D noise (``noise``) give degraded/clean ``pairs`` to tune the model on (``tuning``: the SD1.5
LoRA; the compact model tunes in ``go_core.compact.tuning``); ``repair`` distils the tuned model into the
Gaussians along distance-aware ``arcs`` with the loss of ``loss`` weighted by ``weights`` (λ(π), w(t));
``settings`` are its torch-free knobs and ``data`` reads what the steps need from upstream artifacts."""
