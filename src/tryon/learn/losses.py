"""Training losses of the draping network (positions in metres, losses in cm).

A garment vertex x is split into its closest body point c and its displacement d = x - c
from it. The closest point of the truth is precomputed (`candidates`: the body region
vertices nearest to it); a prediction's is the nearest of those candidates, so the
split follows the prediction while it is near the truth."""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
import torch

CM = 100.0


@dataclass
class LossWeights:
    v2v: float = 1.0
    direction: float = 0.2
    penetration: float = 1.0
    edge: float = 1.0
    deformation: float = 0.5
    laplacian: float = 1.0
    spectral: float = 0.2
    levels: float = 0.3  # the coarse levels' V2V relative to the finest

    def to_dict(self) -> dict:
        return asdict(self)


def closest_split(x: torch.Tensor, body: torch.Tensor, normals: torch.Tensor, cand: torch.Tensor):
    """(c, d, n) of x [B,N,3] among candidate body vertices cand [B,N,K] (ids into body [B,M,3])."""
    b = torch.arange(x.shape[0])[:, None, None]
    pts = body[b, cand]                                   # [B,N,K,3]
    best = ((pts - x[:, :, None]) ** 2).sum(-1).argmin(-1)  # [B,N]
    pick = torch.gather(cand, 2, best[..., None])[..., 0]
    bb = torch.arange(x.shape[0])[:, None]
    c = body[bb, pick]
    return c, x - c, normals[bb, pick]


def edge_lengths(x: torch.Tensor, edges: torch.Tensor) -> torch.Tensor:
    return (x[:, edges[:, 0]] - x[:, edges[:, 1]]).norm(dim=-1)


def deformation_gradients(x: torch.Tensor, faces: torch.Tensor, rest_inv: torch.Tensor) -> torch.Tensor:
    ds = torch.stack([x[:, faces[:, 1]] - x[:, faces[:, 0]], x[:, faces[:, 2]] - x[:, faces[:, 0]]], -1)  # [B,F,3,2]
    return ds @ rest_inv


def uniform_laplacian(x: torch.Tensor, edges: torch.Tensor, n: int) -> torch.Tensor:
    i, j = edges[:, 0], edges[:, 1]
    acc = torch.zeros_like(x).index_add_(1, i, x[:, j]).index_add_(1, j, x[:, i])
    one = torch.ones(len(i), dtype=x.dtype)
    deg = torch.zeros(n, dtype=x.dtype).index_add_(0, i, one).index_add_(0, j, one)
    return x - acc / deg[None, :, None]


class DrapeLoss:
    """All terms of the training loss on one batch; `__call__` returns (total, parts)."""

    def __init__(self, hierarchy, weights: LossWeights, thickness: float = 0.004):
        fine = hierarchy.levels[0]
        self.w = weights
        self.edges = [torch.from_numpy(lv.edges()) for lv in hierarchy.levels]
        self.ns = [lv.n for lv in hierarchy.levels]
        self.faces = torch.from_numpy(fine.faces)
        self.rest_inv = torch.from_numpy(hierarchy.rest_inv.astype(np.float32))
        self.basis = torch.from_numpy(hierarchy.basis.astype(np.float32))
        self.thickness = thickness

    def __call__(self, preds: list[torch.Tensor], truths: list[torch.Tensor], body: torch.Tensor, normals: torch.Tensor,
                 cand: torch.Tensor) -> tuple[torch.Tensor, dict[str, float]]:
        x, y = preds[0], truths[0]
        w = self.w
        parts: dict[str, torch.Tensor] = {}
        cx, dx, nx = closest_split(x, body, normals, cand)
        cy, dy, _ = closest_split(y, body, normals, cand)
        parts["v2v"] = CM * ((cx - cy).abs().sum(-1) + (dx - dy).abs().sum(-1)).mean()
        cos = torch.nn.functional.cosine_similarity(dx, dy, dim=-1)
        far = (dy.norm(dim=-1) > 0.002).float()
        parts["direction"] = ((1 - cos) * far).sum() / far.sum().clamp(min=1)
        parts["penetration"] = CM * torch.relu(0.5 * self.thickness - (dx * nx).sum(-1)).mean()
        ex, ey = edge_lengths(x, self.edges[0]), edge_lengths(y, self.edges[0])
        parts["edge"] = (ex / ey.clamp(min=1e-4) - 1).abs().mean()
        parts["deformation"] = (deformation_gradients(x, self.faces, self.rest_inv)
                                - deformation_gradients(y, self.faces, self.rest_inv)).abs().mean()
        lap = sum(CM * (uniform_laplacian(p, e, n) - uniform_laplacian(t, e, n)).abs().sum(-1).mean()
                  for p, t, e, n in zip(preds, truths, self.edges, self.ns))
        parts["laplacian"] = lap / len(preds)
        parts["spectral"] = CM * torch.einsum("nk,bnd->bkd", self.basis, x - y).abs().mean()
        parts["levels"] = sum((CM * (p - t).norm(dim=-1).mean() for p, t in zip(preds[1:], truths[1:])),
                              torch.zeros(())) / max(1, len(preds) - 1)
        total = sum(getattr(w, k) * v for k, v in parts.items())
        return total, {k: float(v.detach()) for k, v in parts.items()}
