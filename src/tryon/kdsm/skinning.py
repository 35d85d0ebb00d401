"""Skinning the KDSM volume with the body.

Every volume vertex gets linear-blend-skinning weights from Anny's: the vertices within
`anchor` of the skin take the weights at their nearest skin point (face and barycentric
coordinates); the others take the harmonic extension of those (the graph Laplacian of the
tet mesh solved with the anchored vertices as boundary values), so the weights blend
smoothly across the air between arm and torso instead of jumping where the nearest skin
point does. The top `K` bones are kept per vertex.

The volume is built in the drape's pose (the A-pose), so a pose theta moves a volume
vertex by the bones' transforms relative to that pose: x = sum_j w_j G_j(theta) G_j(A)^-1 X.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
import torch
from scipy.sparse.linalg import factorized

from tryon.kdsm.volume import TetVolume

ANCHOR = 0.01   # m: volume vertices this close to the skin (or inside) take the skin's weights
TOP_BONES = 8


@dataclass
class VolumeSkin:
    """Per-vertex bones [N,K] and weights [N,K] (rows sum to 1) of a volume, and the bone
    transforms of the pose it was built in [J,4,4] (their inverses carry it to Anny's rest)."""

    index: np.ndarray
    weight: np.ndarray
    rest_transforms: np.ndarray

    def pose(self, rest_points: np.ndarray, transforms: np.ndarray) -> np.ndarray:
        """Points [N,3] given in the volume's rest pose, skinned to bone transforms [J,4,4]."""
        rel = np.einsum("jab,jbc->jac", np.asarray(transforms, float), np.linalg.inv(self.rest_transforms))
        M = np.einsum("nk,nkab->nab", self.weight, rel[self.index])
        return np.einsum("nab,nb->na", M[:, :3, :3], rest_points) + M[:, :3, 3]


def skin_volume(volume: TetVolume, body_vertices: np.ndarray, body_faces: np.ndarray, weight_index: np.ndarray,
                weight: np.ndarray, rest_transforms: np.ndarray, anchor: float = ANCHOR, top: int = TOP_BONES) -> VolumeSkin:
    """Skinning weights for every vertex of `volume` from the body's (module docstring).
    `body_vertices` are the body in the volume's rest pose, `weight_index`/`weight` [V,K]
    Anny's per-vertex bones and weights, `rest_transforms` [J,4,4] that pose's bone transforms."""
    from tryon.sim.geometry import nearest_surface_locations

    J = len(rest_transforms)
    _, face, bary = nearest_surface_locations(volume.vertices, body_vertices, body_faces)
    surface = _dense(weight_index, weight, J)                                # [V,J] sparse
    corners = body_faces[face]                                               # [N,3]
    near = _blend_rows(surface, corners, bary)                               # [N,J] sparse
    fixed = volume.distance <= anchor
    dense = near.toarray()
    free = ~fixed
    if free.any() and fixed.any():
        dense[free] = 0.0      # every bone's weight off the skin is its harmonic extension (0 where no anchor has it)
        L = _graph_laplacian(volume.tets, len(volume.vertices))
        A = L[free][:, free].tocsc()
        b = -(L[free][:, fixed] @ dense[fixed])
        bones = np.flatnonzero(np.abs(b).sum(0) > 0)
        solve = factorized(A)
        for j in bones:
            dense[free, j] = solve(np.ascontiguousarray(b[:, j]))
    dense = np.clip(dense, 0.0, None)
    order = np.argsort(-dense, axis=1)[:, :top]
    w = np.take_along_axis(dense, order, 1)
    w /= np.maximum(w.sum(1, keepdims=True), 1e-12)
    return VolumeSkin(order.astype(np.int64), w, np.asarray(rest_transforms, float))


def _dense(index: np.ndarray, weight: np.ndarray, J: int) -> sp.csr_matrix:
    rows = np.repeat(np.arange(len(index)), index.shape[1])
    return sp.csr_matrix((weight.ravel(), (rows, index.ravel())), shape=(len(index), J))


def _blend_rows(m: sp.csr_matrix, corners: np.ndarray, bary: np.ndarray) -> sp.csr_matrix:
    n = len(corners)
    B = sp.csr_matrix((bary.ravel(), (np.repeat(np.arange(n), 3), corners.ravel())), shape=(n, m.shape[0]))
    return (B @ m).tocsr()


def _graph_laplacian(tets: np.ndarray, n: int) -> sp.csr_matrix:
    """Uniform graph Laplacian (degree - adjacency) of the tet mesh's edges."""
    pairs = np.concatenate([tets[:, [a, b]] for a in range(4) for b in range(a + 1, 4)])
    pairs = np.unique(np.sort(pairs, 1), axis=0)
    adj = sp.coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    adj = (adj + adj.T).tocsr()
    return (sp.diags(np.asarray(adj.sum(1)).ravel()) - adj).tocsr()


def bone_transforms_np(shape, rotations) -> np.ndarray:
    """Anny's bone transforms [J,4,4] for per-bone rotations [J,3,3] (numpy)."""
    from tryon.body.pose import bone_transforms

    with torch.no_grad():
        return bone_transforms(shape, rotations).numpy()
