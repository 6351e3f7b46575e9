"""Per-training-view affine colour correction for real photos (exposure / white balance that change between
shots), learned with the Gaussians, as 3DGS variants for real captures do (e.g. per-image appearance
transforms): the rendered OBJECT colour of training view ``v`` is mapped by ``c' = A_v·c + α·b_v`` before the
loss, so the Gaussians need not bake one photo's exposure into the shared colours.

Gauge: the transforms are parametrised as deviations with zero mean over the training views
(``A_v = I + D_v − mean D``, ``b_v = e_v − mean e``), so their mean is always the identity: the model's
colours are those of the average training exposure, and a test view (whose exposure is unknown) is rendered
with the identity, i.e. not corrected at all. At initialisation every transform is the identity.

The correction acts on the premultiplied foreground ``C = rgb − (1 − α)·bg`` of a render over background
``bg``; the background itself is not corrected (it is the loss's synthetic colour, not part of the photo).
"""

from __future__ import annotations

import torch

__all__ = ["ViewColorCorrection"]


class ViewColorCorrection:
    """Affine colour transforms of ``n_views`` training views with their own Adam (learning rate ``lr``)."""

    def __init__(self, n_views: int, lr: float) -> None:
        self.deviation = torch.zeros(n_views, 3, 4, requires_grad=True)  # [D_v | e_v]
        self.optimizer = torch.optim.Adam([self.deviation], lr=lr)

    def transforms(self) -> tuple[torch.Tensor, torch.Tensor]:
        """(A [n,3,3], b [n,3]) with mean exactly the identity (zero-mean deviations)."""
        d = self.deviation - self.deviation.mean(dim=0, keepdim=True)
        eye = torch.eye(3, dtype=d.dtype)
        return eye + d[..., :3], d[..., 3]

    def apply(
        self, index: int | None, rgb: torch.Tensor, alpha: torch.Tensor, background: torch.Tensor
    ) -> torch.Tensor:
        """The corrected [H,W,3] render of training view ``index`` (``rgb`` composited over ``background``
        with ``alpha`` [H,W]); ``index`` None (a test view) returns ``rgb`` unchanged."""
        if index is None:
            return rgb
        a = alpha.reshape(rgb.shape[:-1])[..., None]
        bg = background.to(rgb.dtype) * (1.0 - a)
        mat, bias = self.transforms()
        fg = (rgb - bg) @ mat[index].T + a * bias[index]
        return fg + bg

    def step(self) -> None:
        """One Adam step on the accumulated gradient, then clear it."""
        self.optimizer.step()
        self.optimizer.zero_grad(set_to_none=True)

    def summary(self) -> list[list[float]]:
        """Per view: the 3×3 matrix (row-major) then the bias, rounded (for coarse.json)."""
        with torch.no_grad():
            mat, bias = self.transforms()
            rows = torch.cat([mat.reshape(len(mat), 9), bias], dim=1)
        return [[round(float(x), 5) for x in r] for r in rows]

    def state_dict(self) -> dict:
        return {"deviation": self.deviation.detach().clone(), "optimizer": self.optimizer.state_dict()}

    def load_state_dict(self, state: dict) -> None:
        with torch.no_grad():
            self.deviation.copy_(state["deviation"])
        self.optimizer.load_state_dict(state["optimizer"])
