"""Baselines the draping network is judged against, on the same splits.

- `skinning`: the size's reference drape carried to the body by skinning (no learning;
  the network's own prior).
- `nearest`: the training drape of the same gender and size whose body is nearest in
  Anny's (standardised) shape parameters.
- `tailornet-pca`: a TailorNet-style regressor: an MLP from shape parameters, gender and
  size to the coefficients of a PCA of the training drapes, trained with an L2 loss.
"""

from __future__ import annotations

import numpy as np
import torch
from torch import nn

from tryon.learn.data import TrainingSet


class NearestNeighbour:
    def __init__(self, train: TrainingSet):
        self.train = train
        self.mu, self.sd = train.shape.mean(0), train.shape.std(0) + 1e-6

    def predict(self, ts: TrainingSet) -> np.ndarray:
        out = np.zeros_like(ts.truth)
        a = (self.train.shape - self.mu) / self.sd
        for i in range(len(ts.rows)):
            same = np.nonzero((self.train.gender == ts.gender[i]) & (self.train.size == ts.size[i]))[0]
            if len(same) == 0:
                same = np.arange(len(self.train.rows))
            d = np.linalg.norm(a[same] - (ts.shape[i] - self.mu) / self.sd, axis=1)
            out[i] = self.train.truth[same[d.argmin()]]
        return out


class TailorNetPCA:
    """Shape, gender, size -> PCA coefficients of the drape (L2), as TailorNet's shape branch."""

    def __init__(self, train: TrainingSet, sizes: int, components: int = 64, iterations: int = 3000, seed: int = 0):
        torch.manual_seed(seed)
        flat = train.truth.reshape(len(train.rows), -1).astype(np.float64)
        self.mean = flat.mean(0)
        _, _, vt = np.linalg.svd(flat - self.mean, full_matrices=False)
        k = min(components, len(vt))
        self.basis = vt[:k]
        coeff = (flat - self.mean) @ self.basis.T
        self.sizes = sizes
        self.mu, self.sd = train.shape.mean(0), train.shape.std(0) + 1e-6
        self.c_sd = coeff.std(0) + 1e-9
        x = torch.from_numpy(self._inputs(train))
        y = torch.from_numpy((coeff / self.c_sd).astype(np.float32))
        self.net = nn.Sequential(nn.Linear(x.shape[1], 256), nn.ReLU(), nn.Linear(256, 256), nn.ReLU(), nn.Linear(256, k))
        opt = torch.optim.Adam(self.net.parameters(), lr=1e-3, weight_decay=1e-5)
        for _ in range(iterations):
            loss = ((self.net(x) - y) ** 2).mean()
            opt.zero_grad()
            loss.backward()
            opt.step()

    def _inputs(self, ts: TrainingSet) -> np.ndarray:
        onehot = np.eye(self.sizes)[ts.size]
        return np.concatenate([(ts.shape - self.mu) / self.sd, ts.gender[:, None], onehot], 1).astype(np.float32)

    def predict(self, ts: TrainingSet) -> np.ndarray:
        with torch.no_grad():
            c = self.net(torch.from_numpy(self._inputs(ts))).numpy() * self.c_sd
        return (self.mean + c @ self.basis).reshape(ts.truth.shape).astype(np.float32)
