"""The garment's mesh hierarchy for the draping network.

The finest level is the dataset's shared garment topology. Coarser levels triangulate the
same sewing pattern at 2, 4 and 8 times the edge length (seams welded). Levels are tied
by barycentric coordinates in the panels' material (UV) space: a fine vertex lies in a
coarse triangle of its panel (upsampling), a coarse vertex in a fine one (restriction of
a target to a coarse level). The finest level also carries the lowest eigenvectors of
its Laplacian (the spectral branch's basis) and its faces' rest frames (deformation
gradients)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import eigsh

from tryon.garment.pattern import Pattern
from tryon.garment.triangulate import merge_stitched, triangulate_pattern


@dataclass
class Level:
    """One resolution: welded faces, the panel of each face and each face corner's UV."""

    faces: np.ndarray        # [F,3]
    face_panel: np.ndarray   # [F]
    corner_uv: np.ndarray    # [F,3,2]
    n: int

    def vertex_uv(self) -> tuple[np.ndarray, np.ndarray]:
        """A (panel, uv) of every vertex: that of the first face corner it appears in."""
        verts, first = np.unique(self.faces.ravel(), return_index=True)
        if len(verts) != self.n:
            raise ValueError(f"{self.n - len(verts)} vertices of the garment level belong to no face")
        return self.face_panel[first // 3], self.corner_uv.reshape(-1, 2)[first]

    def edges(self) -> np.ndarray:
        e = np.concatenate([self.faces[:, [0, 1]], self.faces[:, [1, 2]], self.faces[:, [2, 0]]])
        return np.unique(np.sort(e, 1), axis=0)

    def laplacian(self) -> sp.csr_matrix:
        """The graph Laplacian D - A (uniform weights)."""
        e = self.edges()
        a = sp.coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(self.n, self.n))
        a = (a + a.T).tocsr()
        return (sp.diags(np.asarray(a.sum(1)).ravel()) - a).tocsr()


def pattern_level(pattern: Pattern, edge_length: float) -> Level:
    mesh = triangulate_pattern(pattern, edge_length)
    pos, faces, corner_uv, _ = merge_stitched(mesh, np.zeros((len(mesh.points2d), 3)))
    return Level(faces.astype(np.int64), mesh.panel_of_vertex[mesh.faces[:, 0]].astype(np.int64), corner_uv, len(pos))


def locate(points_uv: np.ndarray, points_panel: np.ndarray, level: Level) -> tuple[np.ndarray, np.ndarray]:
    """For each (panel, uv) point, the vertices [P,3] and barycentric weights [P,3] of the
    triangle of `level` in that panel that holds it (the nearest one, clipped, for a
    point just outside the discretised outline)."""
    idx = np.zeros((len(points_uv), 3), np.int64)
    w = np.zeros((len(points_uv), 3))
    for panel in np.unique(points_panel):
        q = np.nonzero(points_panel == panel)[0]
        f = np.nonzero(level.face_panel == panel)[0]
        tri = level.corner_uv[f]                                    # [T,3,2]
        a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
        v0, v1 = b - a, c - a
        det = v0[:, 0] * v1[:, 1] - v0[:, 1] * v1[:, 0]
        det = np.where(np.abs(det) < 1e-14, np.nan, det)  # a degenerate triangle holds no point
        p = points_uv[q][:, None, :] - a[None]                       # [Q,T,2]
        l1 = (p[..., 0] * v1[None, :, 1] - p[..., 1] * v1[None, :, 0]) / det
        l2 = (v0[None, :, 0] * p[..., 1] - v0[None, :, 1] * p[..., 0]) / det
        bary = np.stack([1 - l1 - l2, l1, l2], -1)                   # [Q,T,3]
        best = np.nan_to_num(bary.min(-1), nan=-np.inf).argmax(1)
        bw = np.clip(bary[np.arange(len(q)), best], 0.0, None)
        idx[q] = level.faces[f[best]]
        w[q] = bw / bw.sum(1, keepdims=True)
    return idx, w


def interpolation(idx: np.ndarray, w: np.ndarray, n_from: int) -> sp.csr_matrix:
    rows = np.repeat(np.arange(len(idx)), 3)
    return sp.csr_matrix((w.ravel(), (rows, idx.ravel())), shape=(len(idx), n_from))


@dataclass
class GarmentHierarchy:
    """Levels finest first; up[k] maps level k+1 to level k, down[k] level k to k+1."""

    levels: list[Level]
    up: list[sp.csr_matrix]
    down: list[sp.csr_matrix]
    basis: np.ndarray         # [N, K] lowest Laplacian eigenvectors of the finest level
    rest_inv: np.ndarray      # [F,2,2] inverse rest frames (material space) of the finest faces

    @property
    def n(self) -> int:
        return self.levels[0].n

    def to_arrays(self) -> dict[str, np.ndarray]:
        out = {"basis": self.basis.astype(np.float32), "rest_inv": self.rest_inv}
        for k, lv in enumerate(self.levels):
            out[f"l{k}_faces"], out[f"l{k}_panel"], out[f"l{k}_uv"] = lv.faces, lv.face_panel, lv.corner_uv
        for name, mats in (("up", self.up), ("down", self.down)):
            for k, m in enumerate(mats):
                m = m.tocoo()
                out[f"{name}{k}_rc"] = np.stack([m.row, m.col]).astype(np.int64)
                out[f"{name}{k}_w"], out[f"{name}{k}_shape"] = m.data, np.asarray(m.shape)
        return out

    @classmethod
    def from_arrays(cls, a: dict[str, np.ndarray]) -> "GarmentHierarchy":
        levels, k = [], 0
        while f"l{k}_faces" in a:
            f = a[f"l{k}_faces"]
            levels.append(Level(f, a[f"l{k}_panel"], a[f"l{k}_uv"], int(f.max()) + 1))
            k += 1

        def mats(name):
            return [sp.csr_matrix((a[f"{name}{j}_w"], tuple(a[f"{name}{j}_rc"])), shape=tuple(a[f"{name}{j}_shape"]))
                    for j in range(len(levels) - 1)]
        return cls(levels, mats("up"), mats("down"), np.asarray(a["basis"], np.float64), a["rest_inv"])


def build_hierarchy(faces: np.ndarray, corner_uv: np.ndarray, face_panel: np.ndarray, pattern: Pattern,
                    edge_length: float, levels: int = 4, eigenvectors: int = 128) -> GarmentHierarchy:
    """The hierarchy over a garment topology (faces with their corners' UV and panels)."""
    fine = Level(np.asarray(faces, np.int64), np.asarray(face_panel, np.int64), np.asarray(corner_uv, np.float64),
                 int(np.max(faces)) + 1)
    lv = [fine] + [pattern_level(pattern, edge_length * 2 ** k) for k in range(1, levels)]
    up, down = [], []
    for a, b in zip(lv[:-1], lv[1:]):
        panel_a, uv_a = a.vertex_uv()
        panel_b, uv_b = b.vertex_uv()
        up.append(interpolation(*locate(uv_a, panel_a, b), b.n))
        down.append(interpolation(*locate(uv_b, panel_b, a), a.n))
    lap = fine.laplacian().astype(np.float64)
    k = min(eigenvectors, fine.n - 2)
    # shift-invert about a small negative value: the lowest modes of a singular Laplacian
    # (ARPACK starts from a random vector unless given one: fixed, so the basis is reproducible)
    v0 = np.random.default_rng(0).standard_normal(fine.n)
    _, vecs = eigsh(lap, k=k, sigma=-1e-3, which="LM", v0=v0)
    vecs *= np.sign(vecs[np.abs(vecs).argmax(0), np.arange(k)])  # one sign convention per mode
    uv = fine.corner_uv
    dm = np.stack([uv[:, 1] - uv[:, 0], uv[:, 2] - uv[:, 0]], -1)  # [F,2,2], columns are edges
    return GarmentHierarchy(lv, up, down, vecs, np.linalg.inv(dm))
