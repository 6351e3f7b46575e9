"""Image-quality metrics: PSNR, SSIM (the 3DGS window, shared with the training loss), LPIPS v0.1 with
genuine weights (AlexNet / VGG16, pure torch), and the evaluation protocol that combines them."""

from go_core.metrics.evaluate import MetricSuite, composite, error_map, mean_metrics
from go_core.metrics.lpips import LPIPS, lpips_distance
from go_core.metrics.lpips_weights import fetch_lpips_weights
from go_core.metrics.psnr import psnr
from go_core.metrics.ssim import ssim

__all__ = [
    "LPIPS",
    "MetricSuite",
    "composite",
    "error_map",
    "fetch_lpips_weights",
    "lpips_distance",
    "mean_metrics",
    "psnr",
    "ssim",
]
