"""The shape-aware draping network.

- `BodyEncoder`: a 1D CNN along the body region's vertices (Anny's index order keeps
  neighbours mostly together), with the wearer's gender, the garment size and (in a model
  of many fabrics) the fabric's features, to a latent.
- `HierarchicalDecoder`: graph convolutions over the garment mesh from the coarsest of
  four levels to the finest, y = f(A_theta x W) with a learned weight A_theta[i, j] on
  every mesh edge and self loop; each level's features are carried up barycentrically in
  UV space, and each level predicts the correction to the skinned prior (deep supervision).
- `SpectralBranch`: an MLP from the latent to coefficients of the lowest Laplacian
  eigenvectors of the garment, a smooth residual added at the finest level.

The garment is predicted as prior + correction; positions are in metres."""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
import scipy.sparse as sp
import torch
from torch import nn

from tryon.learn.topology import GarmentHierarchy


@dataclass
class NetConfig:
    latent: int = 256
    width: int = 64
    embed: int = 8
    sizes: int = 3
    fabric: int = 0  # fabric features the encoder reads (`tryon.fabric.blend.FEATURE_NAMES`); 0: one fabric
    eigen: int = 128
    spectral: bool = True
    levels: int = 4
    learned_aggregation: bool = True  # False: every neighbour weighs 1 / degree, fixed (an ablation)

    def to_dict(self) -> dict:
        return asdict(self)


def sparse(m: sp.spmatrix) -> torch.Tensor:
    m = m.tocoo()
    return torch.sparse_coo_tensor(np.stack([m.row, m.col]), m.data.astype(np.float32), m.shape,
                                   check_invariants=False).coalesce()


def apply_sparse(m: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
    """m [R,C] applied along the vertex axis of x [B,C,F]."""
    b, n, f = x.shape
    y = torch.sparse.mm(m, x.permute(1, 0, 2).reshape(n, b * f))
    return y.reshape(-1, b, f).permute(1, 0, 2)


class GraphConv(nn.Module):
    """y_i = sum_j theta_ij (W x_j) + b over i's mesh neighbours and itself."""

    def __init__(self, edges: np.ndarray, n: int, cin: int, cout: int, learned: bool = True):
        super().__init__()
        e = np.concatenate([edges, edges[:, ::-1], np.repeat(np.arange(n)[:, None], 2, 1)])
        deg = np.bincount(e[:, 0], minlength=n)
        self.register_buffer("dst", torch.from_numpy(e[:, 0].copy()))
        self.register_buffer("src", torch.from_numpy(e[:, 1].copy()))
        theta = torch.from_numpy((1.0 / deg[e[:, 0]]).astype(np.float32))
        if learned:
            self.theta = nn.Parameter(theta)
        else:
            self.register_buffer("theta", theta)
        self.lin = nn.Linear(cin, cout)
        self.n = n

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        h = self.lin(x)
        out = torch.zeros(h.shape[0], self.n, h.shape[2], dtype=h.dtype)
        return out.index_add_(1, self.dst, h[:, self.src] * self.theta[None, :, None])


class BodyEncoder(nn.Module):
    def __init__(self, cfg: NetConfig, channels: int = 6):
        super().__init__()
        c = [channels, 32, 64, 128, 128, 128]
        layers: list[nn.Module] = []
        for a, b in zip(c[:-1], c[1:]):
            layers += [nn.Conv1d(a, b, 5, stride=2, padding=2), nn.GELU()]
        self.conv = nn.Sequential(*layers, nn.AdaptiveAvgPool1d(8))
        self.fabric = cfg.fabric
        self.head = nn.Sequential(nn.Linear(128 * 8 + 1 + cfg.sizes + cfg.fabric, cfg.latent), nn.GELU(),
                                  nn.Linear(cfg.latent, cfg.latent))

    def forward(self, body: torch.Tensor, gender: torch.Tensor, size: torch.Tensor,
                fabric: torch.Tensor | None = None) -> torch.Tensor:
        """body [B,M,6] (positions and displacement from the mean body, scaled), gender [B],
        size [B,S], fabric [B,F] (normalised features; read only by a model of many fabrics)."""
        h = self.conv(body.transpose(1, 2)).flatten(1)
        parts = [h, gender[:, None].float(), size.float()]
        if self.fabric:
            if fabric is None or fabric.shape[-1] != self.fabric:
                raise ValueError(f"this network reads {self.fabric} fabric features")
            parts.append(fabric.float())
        return self.head(torch.cat(parts, 1))


class HierarchicalDecoder(nn.Module):
    def __init__(self, cfg: NetConfig, hierarchy: GarmentHierarchy):
        super().__init__()
        w, lv = cfg.width, hierarchy.levels[:cfg.levels]
        self.ups = [sparse(m) for m in hierarchy.up[:cfg.levels - 1]]
        self.embed = nn.ParameterList([nn.Parameter(0.1 * torch.randn(l.n, cfg.embed)) for l in lv])
        self.latent = nn.Linear(cfg.latent, w)
        self.blocks = nn.ModuleList()
        self.heads = nn.ModuleList()
        for k, level in enumerate(lv):
            cin = (w if k == len(lv) - 1 else 2 * w) + 3 + cfg.embed
            learned = cfg.learned_aggregation
            self.blocks.append(nn.ModuleList([GraphConv(level.edges(), level.n, cin, w, learned),
                                              GraphConv(level.edges(), level.n, w, w, learned)]))
            self.heads.append(nn.Linear(w, 3))

    def forward(self, latent: torch.Tensor, priors: list[torch.Tensor]) -> list[torch.Tensor]:
        """Corrections [B,N_k,3] per level, finest first; `priors` finest first, in metres."""
        b = latent.shape[0]
        z = self.latent(latent)
        out: list[torch.Tensor] = []
        h = None
        for k in reversed(range(len(self.blocks))):
            n = priors[k].shape[1]
            ctx = z[:, None, :].expand(b, n, -1) if h is None else torch.cat(
                [apply_sparse(self.ups[k], h), z[:, None, :].expand(b, n, -1)], 2)
            x = torch.cat([ctx, priors[k], self.embed[k][None].expand(b, -1, -1)], 2)
            c1, c2 = self.blocks[k]
            h = nn.functional.gelu(c1(x))
            h = h + nn.functional.gelu(c2(h))
            out.append(self.heads[k](h))
        return out[::-1]


class DrapeNet(nn.Module):
    def __init__(self, cfg: NetConfig, hierarchy: GarmentHierarchy):
        super().__init__()
        self.cfg = cfg
        self.encoder = BodyEncoder(cfg)
        self.decoder = HierarchicalDecoder(cfg, hierarchy)
        self.downs = [sparse(m) for m in hierarchy.down[:cfg.levels - 1]]
        cfg.eigen = min(cfg.eigen, hierarchy.basis.shape[1])
        self.register_buffer("basis", torch.from_numpy(hierarchy.basis[:, :cfg.eigen].astype(np.float32)), persistent=False)
        self.spectral = nn.Sequential(nn.Linear(cfg.latent, cfg.latent), nn.GELU(), nn.Linear(cfg.latent, 3 * cfg.eigen)) \
            if cfg.spectral else None
        self.scale = 0.01  # corrections are learned in cm

    def restrict(self, x: torch.Tensor) -> list[torch.Tensor]:
        """x [B,N,3] at every level, finest first."""
        out = [x]
        for d in self.downs:
            out.append(apply_sparse(d, out[-1]))
        return out

    def forward(self, body: torch.Tensor, gender: torch.Tensor, size: torch.Tensor, prior: torch.Tensor,
                fabric: torch.Tensor | None = None) -> list[torch.Tensor]:
        """Predicted garments [B,N_k,3] per level, finest first."""
        latent = self.encoder(body, gender, size, fabric)
        priors = self.restrict(prior)
        centre = prior.mean(1, keepdim=True)
        corr = self.decoder(latent, [p - centre for p in priors])
        out = [p + self.scale * c for p, c in zip(priors, corr)]
        if self.spectral is not None:
            coeff = self.spectral(latent).reshape(-1, self.cfg.eigen, 3)
            out[0] = out[0] + self.scale * torch.einsum("nk,bkd->bnd", self.basis, coeff)
        return out
