"""One rendering API for every backend (compiled CPU extension, gsplat on CUDA, pure-torch reference).

CONTRACT (all backends; owned by the rasterizer work, issue #3):

    render(means, quats, scales, opacities, colors, viewmats, Ks, width, height, *,
           sh_degree=None, background=None, near_plane=0.01, far_plane=1e10,
           antialiased=False, backend="auto") -> RenderOutput

* means [N,3], quats [N,4] (w,x,y,z; unnormalised ok), scales [N,3] (ACTIVATED, i.e. exp(log_scales)),
  opacities [N] (ACTIVATED, sigmoid), colors: SH coefficients [N,K,3] when ``sh_degree`` is given (evaluated
  from each camera centre, +0.5, clamped at 0; degree may be lower than K allows), else RGB [N,3].
* viewmats [C,4,4] world-to-camera (OpenCV convention, see go_core.camera), Ks [C,3,3].
* background: None (black) or [3] / [C,3] RGB added as ``rgb + (1 - alpha) * background``.
* Differentiable w.r.t. means, quats, scales, opacities, colors and viewmats.
* ``backend``: "auto" (gsplat for CUDA tensors, else "cpu"), "cpu", "cuda", "reference".

The maths (projection, tiles, compositing, backward) and the backends are documented in docs/rendering.md.
"""

from go_core.render.api import RenderOutput, render, render_camera, render_gaussians

__all__ = ["RenderOutput", "render", "render_camera", "render_gaussians"]
