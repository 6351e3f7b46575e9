"""go_core: the GaussianObject library (cameras, scenes, Gaussians, rendering, losses, hull, metrics, IO).

It never imports the runner (`go_pipeline`) or the step functions.
"""

__version__ = "0.1.0"
