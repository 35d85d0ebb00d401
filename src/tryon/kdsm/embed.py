"""Embedding cloth in the KDSM: from a posed garment to material-space points and back.

A cloth vertex x in pose theta lies in one or more tets of the posed volume (several where
the posed volume overlaps itself: between arm and torso when the arm comes down). Each
such parent tet t with barycentric coordinates b gives a material point
u = sum_k b_k X_k (the tet's rest-pose corners); skinning that tet to theta gives x back.

- **Method 1** takes any parent (here the one x lies deepest in): no error, but where
  parents change between poses, u jumps, and so does the offset d = u(theta) - u0 the
  network must learn.
- **Method 2** takes the material point from Jin et al.'s body-surface offsets (the cloth
  vertex bound to a skin point, its offset in that point's tangent-normal frame carried
  from the pose back to the rest pose): smooth in theta, but skinning it back through the
  volume does not give x exactly.
- **Hybrid** takes Method 1 where there is one parent, and among several the parent
  whose material point is nearest Method 2's (if nearer than `threshold`, else Method 1's
  parent); then d is smoothed over the cloth mesh
  (screened Poisson: (I + s L) d' = d), trading a little error for a smoother field.

Parents are found with the project's BVH kernels (tryon.sim.geometry.bvh): tet boxes
against point boxes, then exact barycentric tests.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import factorized

from tryon.kdsm.skinning import VolumeSkin
from tryon.kdsm.volume import TetVolume, tet_tree

INSIDE_TOL = 1e-9     # barycentric slack: a point on a shared face belongs to both tets
HYBRID_THRESHOLD = 0.03  # m: a parent this much farther than Method 2's material point is not trusted


@dataclass
class Parents:
    """Every (point, tet) containment: point [K], tet [K], barycentric coordinates [K,4]."""

    point: np.ndarray
    tet: np.ndarray
    bary: np.ndarray

    def count(self, n: int) -> np.ndarray:
        return np.bincount(self.point, minlength=n)


def tet_barycentric(points: np.ndarray, corners: np.ndarray) -> np.ndarray:
    """Barycentric coordinates [P,4] of points [P,3] in tets with corners [P,4,3]."""
    a = corners[:, 0]
    T = np.stack([corners[:, 1] - a, corners[:, 2] - a, corners[:, 3] - a], axis=2)   # [P,3,3] columns
    lam = np.linalg.solve(T, (points - a)[..., None])[..., 0]
    return np.concatenate([1.0 - lam.sum(1, keepdims=True), lam], 1)


def find_parents(points: np.ndarray, x: np.ndarray, tets: np.ndarray, tol: float = INSIDE_TOL, tree=None) -> Parents:
    """All tets (at vertex positions `x`) containing each point; `tree`: their BVH if built."""
    from tryon.sim.geometry import BVH, overlapping_pairs, point_boxes

    points = np.ascontiguousarray(points, np.float64)
    x = np.ascontiguousarray(x, np.float64)
    tree_t = tree if tree is not None else tet_tree(x, tets)
    tree_p = BVH.build(*point_boxes(points, 0.0))
    pairs = overlapping_pairs(tree_p, tree_t)
    if len(pairs) == 0:
        return Parents(np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, 4)))
    bary = tet_barycentric(points[pairs[:, 0]], x[tets[pairs[:, 1]]])
    inside = bary.min(1) >= -tol
    order = np.lexsort((pairs[inside, 1], pairs[inside, 0]))
    return Parents(pairs[inside, 0][order], pairs[inside, 1][order], bary[inside][order])


def find_parents_brute(points: np.ndarray, x: np.ndarray, tets: np.ndarray, tol: float = INSIDE_TOL) -> Parents:
    """`find_parents` by testing every tet (for checking the BVH; O(points x tets))."""
    P, T = len(points), len(tets)
    pi, ti = np.repeat(np.arange(P), T), np.tile(np.arange(T), P)
    bary = tet_barycentric(points[pi], x[tets[ti]])
    inside = bary.min(1) >= -tol
    return Parents(pi[inside], ti[inside], bary[inside])


def nearest_tets(points: np.ndarray, x: np.ndarray, tets: np.ndarray, k: int = 8) -> tuple[np.ndarray, np.ndarray]:
    """For points outside every tet: among the k tets with the nearest centroids, the one
    whose barycentric coordinates are least negative (tet [P], bary [P,4]; extrapolation)."""
    from scipy.spatial import cKDTree

    centroid = x[tets].mean(1)
    _, near = cKDTree(centroid).query(points, k=min(k, len(tets)))
    near = near.reshape(len(points), -1)
    bary = tet_barycentric(np.repeat(points, near.shape[1], 0), x[tets[near.ravel()]]).reshape(len(points), -1, 4)
    best = bary.min(2).argmax(1)
    return near[np.arange(len(points)), best], bary[np.arange(len(points)), best]


@dataclass
class Embedded:
    """One pose's cloth in the volume: parent tet [n], barycentric coordinates [n,4],
    material point [n,3], the number of parents each vertex had [n] (0: outside the
    posed volume, extrapolated)."""

    tet: np.ndarray
    bary: np.ndarray
    material: np.ndarray
    parents: np.ndarray


def _best_per_point(point: np.ndarray, score: np.ndarray) -> np.ndarray:
    """Index of the highest-scoring row of every point that has rows (ties: the first)."""
    if len(point) == 0:
        return np.zeros(0, np.int64)
    order = np.lexsort((-score, point))                    # by point, best first
    first = np.flatnonzero(np.r_[True, point[order][1:] != point[order][:-1]])
    return order[first]


def _deepest(parents: Parents, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Per point, the parent it lies deepest in (largest smallest barycentric coordinate)."""
    tet = -np.ones(n, np.int64)
    bary = np.zeros((n, 4))
    if len(parents.point):
        pick = _best_per_point(parents.point, parents.bary.min(1))
        tet[parents.point[pick]] = parents.tet[pick]
        bary[parents.point[pick]] = parents.bary[pick]
    return tet, bary


def embed(x: np.ndarray, posed: np.ndarray, volume: TetVolume, method: str = "method1",
          surface_material: np.ndarray | None = None, threshold: float = HYBRID_THRESHOLD) -> Embedded:
    """Material points of cloth vertices `x` [n,3] in the volume posed at `posed` [N,3].
    `surface_material` [n,3]: Method 2's material points (tryon.kdsm.offsets), needed by
    'method2' and 'hybrid'."""
    if method not in ("method1", "method2", "hybrid"):
        raise ValueError(f"unknown embedding method {method!r}: method1, method2 or hybrid")
    n = len(x)
    if method == "method2":
        tet, bary = locate_rest(surface_material, volume)
        return Embedded(tet, bary, np.asarray(surface_material, float), np.zeros(n, np.int64))
    parents = find_parents(x, posed, volume.tets)
    count = parents.count(n)
    tet, bary = _deepest(parents, n)
    if (count == 0).any():
        out = np.flatnonzero(count == 0)
        tet[out], bary[out] = nearest_tets(x[out], posed, volume.tets)
    if method == "hybrid" and (count > 1).any():
        if surface_material is None:
            raise ValueError("the hybrid embedding needs Method 2's material points (surface_material)")
        many = count[parents.point] > 1
        p, t, b = parents.point[many], parents.tet[many], parents.bary[many]
        u = np.einsum("kc,kcd->kd", b, volume.vertices[volume.tets[t]])
        gap = np.linalg.norm(u - surface_material[p], axis=1)
        trusted = np.flatnonzero(gap < threshold)    # else Method 1's parent stays
        pick = trusted[_best_per_point(p[trusted], -gap[trusted])]
        tet[p[pick]], bary[p[pick]] = t[pick], b[pick]
    material = np.einsum("nc,ncd->nd", bary, volume.vertices[volume.tets[tet]])
    return Embedded(tet, bary, material, count)


def locate_rest(material: np.ndarray, volume: TetVolume, hint: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Parent tet [n] and barycentric coordinates [n,4] of material points in the rest
    volume (tets do not overlap there: one parent, or a shared face); points outside it
    are extrapolated from the nearest tet. `hint` [n]: tets to try first (the last
    frame's parents: in an animation most points stay in theirs)."""
    material = np.asarray(material, np.float64)
    n = len(material)
    tet = -np.ones(n, np.int64)
    bary = np.zeros((n, 4))
    todo = np.arange(n)
    if hint is not None:
        b = tet_barycentric(material, volume.vertices[volume.tets[hint]])
        kept = b.min(1) >= -INSIDE_TOL
        tet[kept], bary[kept] = hint[kept], b[kept]
        todo = np.flatnonzero(~kept)
    if len(todo):
        parents = find_parents(material[todo], volume.vertices, volume.tets, tree=volume.tree())
        t, b = _deepest(parents, len(todo))
        tet[todo], bary[todo] = t, b
    out = np.flatnonzero(tet < 0)
    if len(out):
        tet[out], bary[out] = nearest_tets(material[out], volume.vertices, volume.tets)
    return tet, bary


def reconstruct(material: np.ndarray, volume: TetVolume, skin: VolumeSkin, transforms: np.ndarray,
                located: tuple[np.ndarray, np.ndarray] | None = None, hint: np.ndarray | None = None) -> np.ndarray:
    """Cloth positions [n,3] in the pose of bone `transforms` from material points [n,3]:
    locate them in the rest volume (`hint`: tets to try first), skin their tets' corners,
    blend."""
    tet, bary = located if located is not None else locate_rest(material, volume, hint)
    corners = np.unique(volume.tets[tet])
    posed = np.zeros_like(volume.vertices)
    posed[corners] = pose_vertices(volume, skin, transforms, corners)
    return np.einsum("nc,ncd->nd", bary, posed[volume.tets[tet]])


def pose_vertices(volume: TetVolume, skin: VolumeSkin, transforms: np.ndarray, which: np.ndarray | None = None) -> np.ndarray:
    """Volume vertices (all, or `which`) skinned to bone `transforms` [J,4,4]."""
    if which is None:
        return skin.pose(volume.vertices, transforms)
    sub = VolumeSkin(skin.index[which], skin.weight[which], skin.rest_transforms)
    return sub.pose(volume.vertices[which], transforms)


def smooth_offsets(d: np.ndarray, faces: np.ndarray, strength: float) -> np.ndarray:
    """Screened Poisson smoothing of a per-vertex field over a triangle mesh:
    (I + strength * L) d' = d with the uniform graph Laplacian L."""
    if strength <= 0:
        return np.asarray(d, float)
    n = len(d)
    e = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    e = np.unique(np.sort(e, 1), axis=0)
    adj = sp.coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(n, n))
    adj = (adj + adj.T).tocsr()
    L = sp.diags(np.asarray(adj.sum(1)).ravel()) - adj
    solve = factorized((sp.identity(n) + strength * L).tocsc())
    return np.stack([solve(np.ascontiguousarray(d[:, k])) for k in range(d.shape[1])], 1)
