"""LightGlue (Lindenberger et al., ICCV 2023) matcher, forward pass only, in pure torch, for DISK features
(128-d descriptors projected to 256; 9 layers of self- and cross-attention with 4 heads and rotary
positional encoding of the normalised keypoints; dual-softmax assignment with matchability).

Parameter names follow the released checkpoints (``transformers.{i}.self_attn.Wqkv`` ...), so the
converted weights load as they are. Early stopping by token confidence (``depth_confidence``) is the
original's; its point pruning (``width_confidence``) only saves time and is not ported: results equal the
original's with pruning disabled.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import nn

DIM, HEADS, LAYERS, INPUT_DIM = 256, 4, 9, 128


def _ffn(dim: int) -> nn.Sequential:
    return nn.Sequential(
        nn.Linear(2 * dim, 2 * dim), nn.LayerNorm(2 * dim), nn.GELU(), nn.Linear(2 * dim, dim)
    )


def _rotate_half(x: torch.Tensor) -> torch.Tensor:
    x1, x2 = x.unflatten(-1, (-1, 2)).unbind(-1)
    return torch.stack((-x2, x1), -1).flatten(-2)


def _rotary(freqs: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
    return t * freqs[0] + _rotate_half(t) * freqs[1]


class _PositionalEncoding(nn.Module):
    def __init__(self, head_dim: int) -> None:
        super().__init__()
        self.Wr = nn.Linear(2, head_dim // 2, bias=False)

    def forward(self, xy: torch.Tensor) -> torch.Tensor:
        p = self.Wr(xy)  # [B,N,hd/2]
        return torch.stack([p.cos(), p.sin()], 0).unsqueeze(-3).repeat_interleave(2, dim=-1)


class _SelfBlock(nn.Module):
    def __init__(self) -> None:
        super().__init__()
        self.Wqkv = nn.Linear(DIM, 3 * DIM)
        self.out_proj = nn.Linear(DIM, DIM)
        self.ffn = _ffn(DIM)

    def forward(self, x: torch.Tensor, enc: torch.Tensor) -> torch.Tensor:
        qkv = self.Wqkv(x).unflatten(-1, (HEADS, -1, 3)).transpose(1, 2)
        q, k, v = _rotary(enc, qkv[..., 0]), _rotary(enc, qkv[..., 1]), qkv[..., 2]
        ctx = F.scaled_dot_product_attention(q.contiguous(), k.contiguous(), v.contiguous())
        msg = self.out_proj(ctx.transpose(1, 2).flatten(-2))
        return x + self.ffn(torch.cat([x, msg], -1))


class _CrossBlock(nn.Module):
    def __init__(self) -> None:
        super().__init__()
        self.to_qk = nn.Linear(DIM, DIM)
        self.to_v = nn.Linear(DIM, DIM)
        self.to_out = nn.Linear(DIM, DIM)
        self.ffn = _ffn(DIM)

    def forward(self, x0: torch.Tensor, x1: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        def heads(t: torch.Tensor) -> torch.Tensor:
            return t.unflatten(-1, (HEADS, -1)).transpose(1, 2)

        scale = (DIM // HEADS) ** -0.25
        qk0, qk1 = heads(self.to_qk(x0)) * scale, heads(self.to_qk(x1)) * scale
        v0, v1 = heads(self.to_v(x0)), heads(self.to_v(x1))
        sim = torch.einsum("bhid,bhjd->bhij", qk0, qk1)
        m0 = torch.einsum("bhij,bhjd->bhid", sim.softmax(-1), v1)
        m1 = torch.einsum("bhji,bhjd->bhid", sim.transpose(-2, -1).softmax(-1).transpose(-2, -1), v0)
        m0, m1 = (self.to_out(m.transpose(1, 2).flatten(-2)) for m in (m0, m1))
        return x0 + self.ffn(torch.cat([x0, m0], -1)), x1 + self.ffn(torch.cat([x1, m1], -1))


class _Layer(nn.Module):
    def __init__(self) -> None:
        super().__init__()
        self.self_attn = _SelfBlock()
        self.cross_attn = _CrossBlock()


class _Assignment(nn.Module):
    def __init__(self) -> None:
        super().__init__()
        self.matchability = nn.Linear(DIM, 1)
        self.final_proj = nn.Linear(DIM, DIM)

    def forward(self, d0: torch.Tensor, d1: torch.Tensor) -> torch.Tensor:
        """Log assignment [B, M+1, N+1] (last row/column: unmatched)."""
        m0, m1 = self.final_proj(d0) / DIM**0.25, self.final_proj(d1) / DIM**0.25
        sim = torch.einsum("bmd,bnd->bmn", m0, m1)
        z0, z1 = self.matchability(d0), self.matchability(d1)
        b, m, n = sim.shape
        scores = sim.new_zeros(b, m + 1, n + 1)
        scores[:, :m, :n] = (
            F.log_softmax(sim, 2)
            + F.log_softmax(sim.transpose(-1, -2), 2).transpose(-1, -2)
            + F.logsigmoid(z0)
            + F.logsigmoid(z1).transpose(1, 2)
        )
        scores[:, :-1, -1] = F.logsigmoid(-z0.squeeze(-1))
        scores[:, -1, :-1] = F.logsigmoid(-z1.squeeze(-1))
        return scores


class _TokenConfidence(nn.Module):
    def __init__(self) -> None:
        super().__init__()
        self.token = nn.Sequential(nn.Linear(DIM, 1), nn.Sigmoid())


def normalize_keypoints(xy: torch.Tensor, size: torch.Tensor) -> torch.Tensor:
    """Pixel coordinates → centred, divided by half the longest image side (``size`` = (w, h))."""
    return (xy - size / 2) / (size.max() / 2)


class LightGlue(nn.Module):
    """``forward(xy0, d0, size0, xy1, d1, size1)`` → (matches [K,2] index pairs, scores [K])."""

    def __init__(self, filter_threshold: float = 0.1, depth_confidence: float = 0.95) -> None:
        super().__init__()
        self.filter_threshold = filter_threshold
        self.depth_confidence = depth_confidence
        self.input_proj = nn.Linear(INPUT_DIM, DIM)
        self.posenc = _PositionalEncoding(DIM // HEADS)
        self.transformers = nn.ModuleList(_Layer() for _ in range(LAYERS))
        self.log_assignment = nn.ModuleList(_Assignment() for _ in range(LAYERS))
        self.token_confidence = nn.ModuleList(_TokenConfidence() for _ in range(LAYERS - 1))

    @staticmethod
    def confidence_threshold(layer: int) -> float:
        return min(max(0.8 + 0.1 * math.exp(-4.0 * layer / LAYERS), 0.0), 1.0)

    @torch.no_grad()
    def forward(
        self,
        xy0: torch.Tensor,
        d0: torch.Tensor,
        size0: torch.Tensor,
        xy1: torch.Tensor,
        d1: torch.Tensor,
        size1: torch.Tensor,
    ) -> tuple[torch.Tensor, torch.Tensor]:
        m, n = len(xy0), len(xy1)
        if m == 0 or n == 0:
            return torch.zeros(0, 2, dtype=torch.long), torch.zeros(0)
        enc0 = self.posenc(normalize_keypoints(xy0, size0)[None])
        enc1 = self.posenc(normalize_keypoints(xy1, size1)[None])
        x0, x1 = self.input_proj(d0[None]), self.input_proj(d1[None])
        for i, layer in enumerate(self.transformers):
            x0 = layer.self_attn(x0, enc0)
            x1 = layer.self_attn(x1, enc1)
            x0, x1 = layer.cross_attn(x0, x1)
            if i == LAYERS - 1 or self.depth_confidence <= 0:
                continue
            token = self.token_confidence[i].token
            conf = torch.cat([token(x0).squeeze(-1), token(x1).squeeze(-1)], -1)
            confident = 1.0 - (conf < self.confidence_threshold(i)).float().sum() / (m + n)
            if confident > self.depth_confidence:
                break
        scores = self.log_assignment[i](x0, x1)[0, :-1, :-1]
        best0, best1 = scores.max(1), scores.max(0)
        idx0 = torch.arange(m)
        mutual = best1.indices[best0.indices] == idx0
        conf0 = torch.where(mutual, best0.values.exp(), torch.zeros(()))
        valid = mutual & (conf0 > self.filter_threshold)
        return torch.stack([idx0[valid], best0.indices[valid]], 1), conf0[valid]
