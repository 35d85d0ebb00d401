"""Normals of a triangle mesh: face normals and the pseudonormals of edges and vertices
(Baerentzen & Aanaes 2005), used to orient obstacle contacts and to sign distances."""

from __future__ import annotations

import math

import numpy as np

from tryon.sim.geometry.primitives import cross, dot, jit, norm, row, scale, sub


def face_normals(x: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Unit normals [F,3] by the right-hand rule on each face's winding (zero if degenerate)."""
    if len(faces) == 0:
        return np.zeros((0, 3))
    n = np.cross(x[faces[:, 1]] - x[faces[:, 0]], x[faces[:, 2]] - x[faces[:, 0]])
    length = np.linalg.norm(n, axis=1, keepdims=True)
    return np.divide(n, length, out=np.zeros_like(n), where=length > 0)


def _unit(v: np.ndarray) -> np.ndarray:
    length = np.linalg.norm(v, axis=1, keepdims=True)
    return np.divide(v, length, out=np.zeros_like(v), where=length > 0)


def vertex_normals(x: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Angle-weighted vertex pseudonormals [N,3] (Thuermer & Wuethrich 1998)."""
    out = np.zeros((len(x), 3))
    if len(faces) == 0:
        return out
    nf = face_normals(x, faces)
    for k in range(3):  # the three corners of every face, vectorised over faces
        a = x[faces[:, k]]
        e1 = _unit(x[faces[:, (k + 1) % 3]] - a)
        e2 = _unit(x[faces[:, (k + 2) % 3]] - a)
        angle = np.arccos(np.clip(np.sum(e1 * e2, 1), -1.0, 1.0))
        np.add.at(out, faces[:, k], angle[:, None] * nf)
    return _unit(out)


def area_vertex_normals(x: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Area-weighted unit vertex normals [N,3] (zero where no face touches a vertex):
    cheaper than `vertex_normals`, and what the learned models were trained with."""
    fn = np.cross(x[faces[:, 1]] - x[faces[:, 0]], x[faces[:, 2]] - x[faces[:, 0]])
    n = np.zeros_like(x)
    for k in range(3):
        np.add.at(n, faces[:, k], fn)
    return _unit(n)


def face_edge_ids(faces: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """For every face corner k, the id [F,3] of the edge (v_k, v_{k+1}) in `edges`
    (-1 when the edge is not listed)."""
    if len(faces) == 0:
        return np.zeros((0, 3), np.int64)
    nv = int(max(faces.max(), edges.max() if len(edges) else 0)) + 1
    ekey = np.sort(edges, 1) @ np.array([nv, 1]) if len(edges) else np.zeros(0, np.int64)
    order = np.argsort(ekey)
    skey = ekey[order]
    fe = np.stack([faces, np.roll(faces, -1, axis=1)], -1)  # [F,3,2]
    fkey = np.sort(fe, -1) @ np.array([nv, 1])
    pos = np.clip(np.searchsorted(skey, fkey), 0, max(len(skey) - 1, 0))
    found = (skey[pos] == fkey) if len(skey) else np.zeros(fkey.shape, bool)
    return np.where(found, order[pos] if len(skey) else 0, -1)


def edge_normals(x: np.ndarray, faces: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """Edge pseudonormals [E,3]: the normalised sum of the adjacent faces' unit normals."""
    out = np.zeros((len(edges), 3))
    if len(edges) == 0 or len(faces) == 0:
        return out
    nf = face_normals(x, faces)
    fe = face_edge_ids(faces, edges)
    for k in range(3):  # the three edges of every face, vectorised over faces
        ok = fe[:, k] >= 0
        np.add.at(out, fe[ok, k], nf[ok])
    return _unit(out)


# --------------------------------------------------------------------------- fast path
_FACE_EDGE_CACHE: dict = {}


def cached_face_edge_ids(faces: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """`face_edge_ids`, memoised on the topology (obstacle topology is fixed in a run)."""
    key = (faces.shape, edges.shape, hash(faces.tobytes()), hash(edges.tobytes()))
    fe = _FACE_EDGE_CACHE.get(key)
    if fe is None:
        if len(_FACE_EDGE_CACHE) >= 8:
            _FACE_EDGE_CACHE.pop(next(iter(_FACE_EDGE_CACHE)))
        fe = np.ascontiguousarray(face_edge_ids(faces, edges))
        _FACE_EDGE_CACHE[key] = fe
    return fe


@jit
def _pseudonormals(x, faces, fe, n_edges):
    """Angle-weighted vertex normals [N,3] and edge normals [E,3] (sum of adjacent unit face
    normals), both normalised; zero for vertices / edges without faces."""
    vn = np.zeros((x.shape[0], 3))
    en = np.zeros((n_edges, 3))
    for f in range(faces.shape[0]):
        a, b, c = row(x, faces[f, 0]), row(x, faces[f, 1]), row(x, faces[f, 2])
        nn = cross(sub(b, a), sub(c, a))
        length = norm(nn)
        if length <= 0.0:
            continue
        n = scale(nn, 1.0 / length)
        pts = (a, b, c)
        for k in range(3):
            p = pts[k]
            u = sub(pts[(k + 1) % 3], p)
            v = sub(pts[(k + 2) % 3], p)
            cos = dot(u, v) / max(norm(u) * norm(v), 1e-300)
            angle = math.acos(min(max(cos, -1.0), 1.0))
            i = faces[f, k]
            for d in range(3):
                vn[i, d] += angle * n[d]
            e = fe[f, k]
            if e >= 0:
                for d in range(3):
                    en[e, d] += n[d]
    for out in (vn, en):
        for i in range(out.shape[0]):
            length = norm(row(out, i))
            if length > 0.0:
                for d in range(3):
                    out[i, d] /= length
    return vn, en


def mesh_edges(faces: np.ndarray) -> np.ndarray:
    """The unique edges [E,2] (sorted vertex pairs) of a triangle mesh."""
    pairs = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    return np.unique(np.sort(pairs, axis=1), axis=0)


_EDGES_CACHE: dict = {}


def cached_mesh_edges(faces: np.ndarray) -> np.ndarray:
    """`mesh_edges`, memoised on the topology (an obstacle's faces do not change during a run)."""
    key = (faces.shape, hash(faces.tobytes()))
    edges = _EDGES_CACHE.get(key)
    if edges is None:
        if len(_EDGES_CACHE) >= 8:
            _EDGES_CACHE.pop(next(iter(_EDGES_CACHE)))
        edges = np.ascontiguousarray(mesh_edges(faces))
        _EDGES_CACHE[key] = edges
    return edges


def obstacle_normals(ob: np.ndarray, ob_faces: np.ndarray, ob_edges: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Outward vertex and edge pseudonormals of the obstacle soup."""
    fe = cached_face_edge_ids(ob_faces, ob_edges)
    return _pseudonormals(ob, ob_faces, fe, len(ob_edges))


def obstacle_normals_near(ob: np.ndarray, ob_faces: np.ndarray, ob_edges: np.ndarray,
                          face_ids: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """`obstacle_normals`, exact at the vertices and edges of the faces `face_ids` (zero
    elsewhere): only those faces' one-ring is visited, so a step whose contacts touch a
    small part of a large body does not pay for all of it."""
    touched = np.zeros(len(ob_faces), bool)
    touched[face_ids] = True
    near = np.zeros(len(ob), bool)
    near[ob_faces[touched].ravel()] = True
    ring = near[ob_faces].any(1)  # every face around those faces' vertices
    fe = cached_face_edge_ids(ob_faces, ob_edges)
    return _pseudonormals(ob, np.ascontiguousarray(ob_faces[ring]), np.ascontiguousarray(fe[ring]), len(ob_edges))
