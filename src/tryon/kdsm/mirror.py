"""Left-right mirroring of a pose dataset's examples: twice the training data for free.

The body is mirror-symmetric about x = 0 (Anny's rest body is, to round-off) and so is
the garment's pattern, so the mirror image of a simulated pose (x -> -x) is as good a
sample as the pose itself. A pose mirrors by swapping each `.L` bone with its `.R` bone
and reflecting its rotation (M R M, M = diag(-1, 1, 1); the rotations act in the rest
pose's world axes about the bone heads). The cloth mirrors through its pattern: vertex i
takes the reflected position of the point of the partner panel (front to front, left
sleeve to right sleeve) at i's material coordinates reflected across the panel's
left-right axis, interpolated in that panel's triangle. The triangulation need not be
symmetric. Which material axis is the panel's left-right, and which panel is whose
partner, are read off the rest drape (the choice that mirrors it onto itself best).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tryon.errors import TryonError

REFLECT = np.diag([-1.0, 1.0, 1.0])


def mirror_pose(pose: np.ndarray, labels: list[str]) -> np.ndarray:
    """Per-bone axis-angle [J,3] of the mirrored pose."""
    pose = np.asarray(pose, np.float64)
    out = pose * np.array([1.0, -1.0, -1.0])         # M R(w) M = R(det M * M w)
    index = {name: j for j, name in enumerate(labels)}
    for j, name in enumerate(labels):
        if name.endswith((".L", ".R")):
            other = name[:-1] + ("R" if name.endswith(".L") else "L")
            if other not in index:
                raise TryonError(f"bone {name} has no mirror {other}")
            out[index[other]] = pose[j] * np.array([1.0, -1.0, -1.0])
    return out


@dataclass
class MirrorMap:
    """For each garment vertex, the partner-panel triangle [n] and barycentric
    coordinates [n,3] of its mirrored material point; `rest_error_m`: how far the
    mirrored rest drape lies from the rest drape (mean), the map's own check."""

    faces: np.ndarray
    face: np.ndarray
    bary: np.ndarray
    rest_error_m: float

    def cloth(self, x: np.ndarray) -> np.ndarray:
        """The mirrored cloth [n,3] (positions of the mirrored sample, vertex for vertex)."""
        x = np.asarray(x, np.float64)
        at = np.einsum("nk,nkd->nd", self.bary, x[self.faces[self.face]])
        return at @ REFLECT.T

    @classmethod
    def build(cls, x_rest: np.ndarray, faces: np.ndarray, corner_uv: np.ndarray, face_panel: np.ndarray,
              tolerance: float = 0.01) -> "MirrorMap":
        """The map for a garment whose rest drape `x_rest` sits on a mirror-symmetric body."""
        x_rest, faces = np.asarray(x_rest, np.float64), np.asarray(faces)
        corner_uv, face_panel = np.asarray(corner_uv, np.float64), np.asarray(face_panel)
        vertex_face, vertex_corner = _first_face(faces, len(x_rest))
        uv = corner_uv[vertex_face, vertex_corner]
        panel = face_panel[vertex_face]
        face = np.zeros(len(x_rest), np.int64)
        bary = np.zeros((len(x_rest), 3))
        for p in np.unique(panel):
            at = np.flatnonzero(panel == p)
            best = None
            for q in np.unique(face_panel):
                mine = np.flatnonzero(face_panel == q)
                for flip in ((1.0, -1.0), (-1.0, 1.0), (1.0, 1.0)):
                    centre = 0.5 * (corner_uv[mine].reshape(-1, 2).min(0) + corner_uv[mine].reshape(-1, 2).max(0))
                    target = centre + (uv[at] - centre) * np.array(flip)
                    f, b = _locate(target, corner_uv[mine])
                    moved = np.einsum("nk,nkd->nd", b, x_rest[faces[mine[f]]]) @ REFLECT.T
                    err = float(np.linalg.norm(moved - x_rest[at], axis=1).mean())
                    if best is None or err < best[0]:
                        best = (err, mine[f], b)
            face[at], bary[at] = best[1], best[2]
        m = cls(faces, face, bary, 0.0)
        m.rest_error_m = float(np.linalg.norm(m.cloth(x_rest) - x_rest, axis=1).mean())
        if m.rest_error_m > tolerance:
            raise TryonError(f"the garment does not mirror onto itself (mean {100 * m.rest_error_m:.1f} cm off): "
                             "mirroring needs a symmetric pattern on a symmetric body")
        return m


def _first_face(faces: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """A face [n] and corner [n] holding each vertex (for its material coordinates)."""
    face, corner = np.full(n, -1, np.int64), np.zeros(n, np.int64)
    flat = faces.ravel()
    order = np.argsort(flat, kind="stable")
    first = order[np.r_[0, np.flatnonzero(np.diff(flat[order])) + 1]]
    face[flat[first]], corner[flat[first]] = first // 3, first % 3
    return face, corner


def _locate(points: np.ndarray, tri_uv: np.ndarray, k: int = 12) -> tuple[np.ndarray, np.ndarray]:
    """The triangle [P] (of tri_uv [T,3,2]) holding each 2D point, or the nearest one, and
    the barycentric coordinates [P,3] (clamped into the triangle)."""
    from scipy.spatial import cKDTree

    _, near = cKDTree(tri_uv.mean(1)).query(points, k=min(k, len(tri_uv)))
    near = near.reshape(len(points), -1)
    a, b, c = (tri_uv[near][:, :, i] for i in range(3))
    v0, v1, v2 = b - a, c - a, points[:, None] - a
    d00, d01, d11 = (v0 * v0).sum(-1), (v0 * v1).sum(-1), (v1 * v1).sum(-1)
    d20, d21 = (v2 * v0).sum(-1), (v2 * v1).sum(-1)
    den = np.where(np.abs(d00 * d11 - d01 ** 2) > 1e-18, d00 * d11 - d01 ** 2, 1e-18)
    w1, w2 = (d11 * d20 - d01 * d21) / den, (d00 * d21 - d01 * d20) / den
    bary = np.stack([1 - w1 - w2, w1, w2], -1)
    pick = bary.min(-1).argmax(1)
    rows = np.arange(len(points))
    out = np.clip(bary[rows, pick], 0.0, None)
    return near[rows, pick], out / out.sum(1, keepdims=True)
