"""Image-quality metrics: PSNR (``psnr``), SSIM (``ssim``: the 3DGS window, shared with the training loss),
LPIPS v0.1 with genuine weights (``lpips``, ``lpips_weights``: AlexNet / VGG16, pure torch), the evaluation
protocol that combines them (``evaluate``), and the geometry metrics (``geometry``, ``error_split``,
``mesh_render``).

This package's ``__init__`` imports nothing: import from the module. A step that needs one metric (the
restorer choice's PSNR, the repair's LPIPS loss) then does not carry the evaluation protocol in its cache
key (go_pipeline.codehash), so changing how eval scores does not rerun the tuning and the repair.
"""
