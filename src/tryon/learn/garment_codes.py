"""Garment codes: a point-cloud autoencoder for garments of any topology (fabric from video,
docs/FABRIC_FROM_VIDEO.md), after the two-level autoencoder of chapter 4.

A garment is a point cloud: `CLOUD` points drawn on its surface by area (any mesh, any
garment type). Level one: `REPS` representative points by farthest-point sampling; level
two: each one's local patch, its `PATCH` nearest points relative to it. The encoder reads
every patch with a shared point MLP (max-pooled), joins it to its representative point,
and max-pools the patches into one code of `CODE` numbers. The decoder gives the
representative points from the code, then each patch from the code and its point. The
loss is the Chamfer distance of the representative points and of the whole cloud; the
cloud is centred on its centroid (metres, not scaled: a code keeps the garment's size).
One latent space holds every garment type.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
import torch
from torch import nn

CLOUD, REPS, PATCH, CODE = 1024, 64, 16, 128


@dataclass
class CodeConfig:
    cloud: int = CLOUD
    reps: int = REPS
    patch: int = PATCH
    code: int = CODE
    width: int = 128

    def to_dict(self) -> dict:
        return asdict(self)


def surface_points(x: np.ndarray, faces: np.ndarray, count: int, rng: np.random.Generator) -> np.ndarray:
    """`count` points drawn uniformly by area on the mesh (x [V,3], faces [F,3])."""
    tri = x[faces]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    face = rng.choice(len(faces), size=count, p=area / area.sum())
    u, v = rng.random(count), rng.random(count)
    flip = u + v > 1
    u[flip], v[flip] = 1 - u[flip], 1 - v[flip]
    t = tri[face]
    return (t[:, 0] + u[:, None] * (t[:, 1] - t[:, 0]) + v[:, None] * (t[:, 2] - t[:, 0])).astype(np.float32)


def farthest_points(p: torch.Tensor, count: int) -> torch.Tensor:
    """Indices [B,count] of farthest-point samples of clouds p [B,N,3] (from point 0)."""
    b, n, _ = p.shape
    idx = torch.zeros(b, count, dtype=torch.long)
    dist = torch.full((b, n), float("inf"))
    last = torch.zeros(b, dtype=torch.long)
    rows = torch.arange(b)
    for k in range(count):
        idx[:, k] = last
        d = ((p - p[rows, last][:, None]) ** 2).sum(-1)
        dist = torch.minimum(dist, d)
        last = dist.argmax(1)
    return idx


def chamfer(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Mean symmetric Chamfer distance (m, not squared) of clouds a [B,N,3] and b [B,M,3], per cloud."""
    d = torch.cdist(a, b)
    return 0.5 * (d.min(2).values.mean(1) + d.min(1).values.mean(1))


class GarmentCodes(nn.Module):
    def __init__(self, config: CodeConfig | None = None):
        super().__init__()
        c = self.config = config or CodeConfig()
        w = c.width
        self.patch_mlp = nn.Sequential(nn.Linear(3, w // 2), nn.ReLU(), nn.Linear(w // 2, w), nn.ReLU())
        self.rep_mlp = nn.Sequential(nn.Linear(w + 3, 2 * w), nn.ReLU(), nn.Linear(2 * w, 2 * w))
        self.to_code = nn.Linear(2 * w, c.code)
        self.to_reps = nn.Sequential(nn.Linear(c.code, 2 * w), nn.ReLU(), nn.Linear(2 * w, c.reps * 3))
        self.to_patch = nn.Sequential(nn.Linear(c.code + 3, 2 * w), nn.ReLU(), nn.Linear(2 * w, c.patch * 3))

    def levels(self, cloud: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(representative points [B,R,3], their patches [B,R,P,3] relative to them)."""
        c = self.config
        rows = torch.arange(len(cloud))[:, None]
        reps = cloud[rows, farthest_points(cloud, c.reps)]
        near = torch.cdist(reps, cloud).topk(c.patch, dim=2, largest=False).indices  # [B,R,P]
        patches = cloud[rows[:, :, None], near] - reps[:, :, None]
        return reps, patches

    def encode(self, cloud: torch.Tensor) -> torch.Tensor:
        """Codes [B,CODE] of centred clouds [B,N,3]."""
        reps, patches = self.levels(cloud)
        local = self.patch_mlp(patches).max(2).values          # [B,R,W]
        joined = self.rep_mlp(torch.cat([local, reps], -1))    # [B,R,2W]
        return self.to_code(joined.max(1).values)

    def decode(self, code: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(representative points [B,R,3], the whole cloud [B,R*P,3])."""
        c = self.config
        reps = self.to_reps(code).view(-1, c.reps, 3)
        z = code[:, None].expand(-1, c.reps, -1)
        patches = self.to_patch(torch.cat([z, reps], -1)).view(-1, c.reps, c.patch, 3)
        return reps, (reps[:, :, None] + patches).reshape(len(code), -1, 3)

    def loss(self, cloud: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(training loss, the whole cloud's Chamfer distance per garment)."""
        true_reps, _ = self.levels(cloud)
        reps, whole = self.decode(self.encode(cloud))
        per_cloud = chamfer(whole, cloud)
        return chamfer(reps, true_reps).mean() + per_cloud.mean(), per_cloud


def centred_cloud(x: np.ndarray, faces: np.ndarray, rng: np.random.Generator, count: int = CLOUD) -> np.ndarray:
    """A garment's surface cloud [count,3], centred on its centroid."""
    p = surface_points(x, faces, count, rng)
    return p - p.mean(0)
