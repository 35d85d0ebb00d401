"""Body-surface offsets (Jin et al. 2020, "A pixel-based framework for data-driven
clothing"): each cloth vertex bound to a point of the skin (the nearest to it in the rest
drape: a face and barycentric coordinates) and described, in any pose, by its offset from
that point in the point's frame (two tangent directions and the normal). The baseline
predicts these offsets; the KDSM's Method 2 carries a posed vertex back to the rest pose
through them."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class SurfaceBinding:
    """Skin face [n] and barycentric coordinates [n,3] of every cloth vertex."""

    face: np.ndarray
    bary: np.ndarray

    @classmethod
    def bind(cls, x: np.ndarray, body_vertices: np.ndarray, body_faces: np.ndarray) -> "SurfaceBinding":
        from tryon.sim.geometry import nearest_surface_locations

        _, face, bary = nearest_surface_locations(x, body_vertices, body_faces)
        return cls(face, bary)

    def frames(self, body_vertices: np.ndarray, body_faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Skin points [n,3] and frames [n,3,3] (columns: tangent, bitangent, normal) in the
        body's current pose. The normal is interpolated from the vertices' normals, so it turns smoothly across faces (angle-weighted pseudonormals of the vertices); the tangent is the face's first edge made
        orthogonal to it."""
        corners = body_faces[self.face]
        p = body_vertices[corners]                                   # [n,3,3]
        origin = np.einsum("nk,nkd->nd", self.bary, p)
        from tryon.sim.geometry import vertex_normals

        vn = vertex_normals(body_vertices, body_faces)
        n = _unit(np.einsum("nk,nkd->nd", self.bary, vn[corners]))
        e = p[:, 1] - p[:, 0]
        t = _unit(e - np.sum(e * n, 1, keepdims=True) * n)
        return origin, np.stack([t, np.cross(n, t), n], axis=2)

    def offsets(self, x: np.ndarray, body_vertices: np.ndarray, body_faces: np.ndarray) -> np.ndarray:
        """Each vertex's offset [n,3] from its skin point, in that point's frame."""
        origin, R = self.frames(body_vertices, body_faces)
        return np.einsum("nji,nj->ni", R, x - origin)

    def positions(self, offsets: np.ndarray, body_vertices: np.ndarray, body_faces: np.ndarray) -> np.ndarray:
        """Cloth positions [n,3] from offsets in the body's current pose (the inverse of `offsets`)."""
        origin, R = self.frames(body_vertices, body_faces)
        return origin + np.einsum("nij,nj->ni", R, offsets)


def _unit(a: np.ndarray) -> np.ndarray:
    return a / np.maximum(np.linalg.norm(a, axis=-1, keepdims=True), 1e-12)
