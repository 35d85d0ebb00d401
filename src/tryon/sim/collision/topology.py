"""Per-mesh data that depends only on the topology, cached across calls: which vertices
and edges each face "owns" (so that a face-face BVH traversal tests every vertex-face and
edge-edge pair exactly once, as in ARCSim) and the BVH topology over the faces (refitted
to new positions, rebuilt every few uses so that it follows large motions)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tryon.sim.geometry.bvh import LEAF_SIZE, BVH, build_tree, refit_tree
from tryon.sim.geometry.normals import face_edge_ids
from tryon.sim.geometry.primitives import jit

REBUILD_EVERY = 16  # uses of a cached BVH topology before it is rebuilt
_CACHE_SIZE = 16


@jit
def fingerprint(a: np.ndarray) -> int:
    """64-bit FNV-1a style hash of an int64 array's values (cheap cache key)."""
    h = np.uint64(14695981039346656037)
    prime = np.uint64(1099511628211)
    flat = a.ravel()
    for i in range(flat.shape[0]):
        h = (h ^ np.uint64(flat[i] & 0xFFFFFFFFFFFF)) * prime
    return h


@dataclass
class MeshTopology:
    """faces [F,3], edges [E,2], face_edges [F,3] (edge id of (v_k, v_k+1)) and the
    vertices / edges owned by each face: own_vertices [F,3], own_edges [F,3], the first
    n_own_vertices [F] / n_own_edges [F] entries of each row valid (the rest -1). A vertex
    or edge belongs to the lowest-numbered face that contains it."""

    faces: np.ndarray
    edges: np.ndarray
    face_edges: np.ndarray
    own_vertices: np.ndarray
    own_edges: np.ndarray
    n_own_vertices: np.ndarray
    n_own_edges: np.ndarray

    @classmethod
    def create(cls, faces: np.ndarray, edges: np.ndarray, n_vertices: int) -> "MeshTopology":
        f_count = len(faces)
        fe = np.ascontiguousarray(face_edge_ids(faces, edges), dtype=np.int64)
        ids = np.arange(f_count)
        owner_v = np.full(max(n_vertices, 1), f_count)
        owner_e = np.full(max(len(edges), 1), f_count)
        for k in range(3):  # the three corners / edges of every face, vectorised over faces
            np.minimum.at(owner_v, faces[:, k], ids)
            ok = fe[:, k] >= 0
            np.minimum.at(owner_e, fe[ok, k], ids[ok])
        own_v = _valid_first(np.where(owner_v[faces] == ids[:, None], faces, -1))
        own_e = _valid_first(np.where((fe >= 0) & (owner_e[np.maximum(fe, 0)] == ids[:, None]), fe, -1))
        return cls(faces, edges, fe, own_v, own_e, (own_v >= 0).sum(1), (own_e >= 0).sum(1))


def _valid_first(a: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(np.take_along_axis(a, np.argsort(a < 0, axis=1, kind="stable"), axis=1))


_TOPOLOGIES: dict = {}


def _remember(cache: dict, key, value) -> None:
    if len(cache) >= _CACHE_SIZE:
        cache.pop(next(iter(cache)))
    cache[key] = value


def mesh_topology(faces: np.ndarray, edges: np.ndarray, n_vertices: int) -> MeshTopology:
    """The (cached) `MeshTopology` of a triangle mesh."""
    key = (faces.shape, edges.shape, n_vertices, int(fingerprint(faces)), int(fingerprint(edges)))
    topo = _TOPOLOGIES.get(key)
    if topo is None:
        topo = MeshTopology.create(faces, edges, n_vertices)
        _remember(_TOPOLOGIES, key, topo)
    return topo


_TREE_PARTS = ("order", "child", "first", "count")


class TreeCache:
    """BVH topologies over face lists, each refitted to new boxes on use and rebuilt every
    REBUILD_EVERY uses. The tree a query traverses decides the order of its candidate pairs,
    and with it the last bits of a step's result, so each simulation owns one cache (its
    `CollisionScene` holds it): its result does not depend on what else ran, or runs, in
    the process, and a checkpoint carries the cache to repeat the uninterrupted run."""

    def __init__(self) -> None:
        self._trees: dict = {}

    def __len__(self) -> int:
        return len(self._trees)

    def tree(self, faces: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> BVH:
        """A BVH over the face boxes (lo, hi): this face list's cached topology refitted, or
        a fresh build every REBUILD_EVERY uses."""
        if len(faces) == 0:
            return BVH.build(lo, hi)
        key = (faces.shape, int(fingerprint(faces)))
        entry = self._trees.get(key)
        if entry is None or entry[4] >= REBUILD_EVERY:
            order, child, first, count = build_tree(lo, hi, LEAF_SIZE)
            entry = [order, child, first, count, 0]
            _remember(self._trees, key, entry)
        entry[4] += 1
        order, child, first, count = entry[:4]
        nlo, nhi = refit_tree(order, child, first, count, lo, hi)
        return BVH(order, child, first, count, nlo, nhi, lo, hi)

    def export(self) -> dict[str, np.ndarray]:
        """The cached topologies and their use counters as plain arrays (for checkpoints)."""
        out: dict[str, np.ndarray] = {}
        for i, (key, entry) in enumerate(self._trees.items()):
            shape, fp = key
            out[f"bvh{i}_key"] = np.array([*shape, entry[4]], dtype=np.int64)
            out[f"bvh{i}_fingerprint"] = np.array([fp], dtype=np.uint64)
            for name, a in zip(_TREE_PARTS, entry[:4]):
                out[f"bvh{i}_{name}"] = a
        return out

    def load(self, arrays: dict[str, np.ndarray]) -> None:
        """Replace the cached topologies by ones saved with `export` (checked first: the
        compiled traversal does not check bounds)."""
        trees = {}
        i = 0
        while f"bvh{i}_key" in arrays:
            key = np.asarray(arrays[f"bvh{i}_key"]).reshape(-1)
            fp = np.asarray(arrays[f"bvh{i}_fingerprint"]).reshape(-1)
            if key.dtype.kind not in "iu" or len(key) != 3 or fp.dtype != np.uint64 or len(fp) != 1:
                raise ValueError(f"cached BVH {i}: malformed key")
            parts = [np.ascontiguousarray(arrays[f"bvh{i}_{name}"]) for name in _TREE_PARTS]
            _check_tree(int(key[0]), *parts)
            trees[(tuple(int(k) for k in key[:-1]), int(fp[0]))] = [*parts, int(key[-1])]
            i += 1
        self._trees = trees


_SHARED_TREES = TreeCache()  # for queries made outside a simulation


def face_tree(faces: np.ndarray, lo: np.ndarray, hi: np.ndarray, cache: TreeCache | None = None) -> BVH:
    """A BVH over the face boxes (lo, hi) from `cache` (a simulation's own), or from the
    cache shared by queries made outside a simulation."""
    return (_SHARED_TREES if cache is None else cache).tree(faces, lo, hi)


def _check_tree(n_faces: int, order: np.ndarray, child: np.ndarray, first: np.ndarray, count: np.ndarray) -> None:
    """A tree the compiled traversal can walk without reading outside its arrays (numba
    does not check bounds): `build_tree`'s layout over `n_faces` primitives."""
    nodes = len(first)
    ok = (all(a.dtype == np.int64 for a in (order, child, first, count)) and order.shape == (n_faces,)
          and child.shape == (nodes, 2) and count.shape == (nodes,)
          and np.array_equal(np.sort(order), np.arange(n_faces))
          and child.min(initial=-1) >= -1 and child.max(initial=-1) < nodes
          and first.min(initial=0) >= 0 and count.min(initial=0) >= 0 and np.all(first + count <= n_faces))
    if not ok:
        raise ValueError("a cached BVH does not fit its mesh")
