"""The uniform contact representation shared by proximity penalties, impact zones and the
differentiable QP layer.

A contact c involves four points p_k with ids idx[c, k] (cloth vertex idx >= 0, obstacle
vertex -idx-1 when idx < 0), weights w[c, k] with sum_k w[c, k] = 0 and a unit normal
n[c]; its gap is d = sum_k w_k n . p_k, positive on the side the primitives are meant to
stay on.

- vertex-face (p0 the vertex, p1..p3 the face): w = (1, -b0, -b1, -b2);
- edge-edge (edges p0p1 and p2p3): w = (1-a, a, -(1-b), -b).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np

from tryon.errors import MeshError
from tryon.sim.geometry.inputs import as_points

VF_SELF = 0  # cloth vertex - cloth face
EE_SELF = 1  # cloth edge - cloth edge
VF_OBSTACLE = 2  # cloth vertex - obstacle face
FV_OBSTACLE = 3  # obstacle vertex - cloth face
EE_OBSTACLE = 4  # cloth edge - obstacle edge
KIND_NAMES = ("vf_self", "ee_self", "vf_obstacle", "fv_obstacle", "ee_obstacle")


@dataclass
class Contacts:
    """A batch of contacts (see the module docstring). `d` is the gap when detected and
    `time` the time of impact in [0, 1] (0 for proximity contacts)."""

    idx: np.ndarray = field(default_factory=lambda: np.zeros((0, 4), np.int64))
    w: np.ndarray = field(default_factory=lambda: np.zeros((0, 4)))
    n: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    d: np.ndarray = field(default_factory=lambda: np.zeros(0))
    kind: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int8))
    time: np.ndarray = field(default_factory=lambda: np.zeros(0))

    @classmethod
    def empty(cls) -> "Contacts":
        return cls()

    def __len__(self) -> int:
        return int(self.idx.shape[0])

    def __add__(self, other: "Contacts") -> "Contacts":
        return Contacts.concatenate([self, other])

    @staticmethod
    def concatenate(parts: Sequence["Contacts"]) -> "Contacts":
        parts = [p for p in parts if len(p)]
        if not parts:
            return Contacts.empty()
        if len(parts) == 1:
            return parts[0]
        return Contacts(
            np.concatenate([p.idx for p in parts]),
            np.concatenate([p.w for p in parts]),
            np.concatenate([p.n for p in parts]),
            np.concatenate([p.d for p in parts]),
            np.concatenate([p.kind for p in parts]),
            np.concatenate([p.time for p in parts]),
        )

    def select(self, which: np.ndarray) -> "Contacts":
        """The contacts picked by a boolean mask or an index array."""
        return Contacts(self.idx[which], self.w[which], self.n[which], self.d[which], self.kind[which], self.time[which])

    def points(self, x: np.ndarray, ob: np.ndarray | None) -> np.ndarray:
        """Positions [C,4,3] of the contact points, cloth from x and obstacle from ob."""
        cloth = self.idx >= 0
        pts = x[np.where(cloth, self.idx, 0)]
        if (~cloth).any():
            if ob is None or len(ob) == 0:
                raise MeshError("contacts refer to obstacle vertices but no obstacle positions were given")
            pts = np.where(cloth[..., None], pts, ob[np.where(cloth, 0, -self.idx - 1)])
        return pts

    def gaps(self, x: Any, ob: Any = None) -> np.ndarray:
        """Gaps d_c = sum_k w_ck n_c . p_k at cloth positions x and obstacle positions ob."""
        if len(self) == 0:
            return np.zeros(0)
        x = as_points(x, "x")
        ob = None if ob is None else as_points(ob, "ob")
        return np.einsum("ck,ckd,cd->c", self.w, self.points(x, ob), self.n)

    def without_joined(self, alias: np.ndarray | None) -> "Contacts":
        """The contacts left after dropping self contacts between vertices that `alias`
        joins (stitched vertices share an alias: to contact handling they are one vertex,
        as two faces sharing a vertex are never in contact)."""
        if alias is None or len(self) == 0:
            return self
        own = (self.kind == VF_SELF) | (self.kind == EE_SELF)
        if not own.any():
            return self
        a = alias[np.where(self.idx >= 0, self.idx, 0)]
        side_a = np.where((self.kind == VF_SELF)[:, None], a[:, :1].repeat(2, 1), a[:, :2])
        side_b = np.where((self.kind == VF_SELF)[:, None], a[:, 1:], np.concatenate([a[:, 2:], a[:, 2:3]], 1))
        joined = (side_a[:, :, None] == side_b[:, None, :]).any(axis=(1, 2)) & own
        return self.select(~joined) if joined.any() else self

    def counts(self) -> dict[str, int]:
        """Number of contacts of each kind."""
        return {name: int(np.sum(self.kind == k)) for k, name in enumerate(KIND_NAMES)}


def stitch_alias(stitches: Any, n_vertices: int) -> np.ndarray | None:
    """One id per cloth vertex, shared by vertices that stitches join (directly or through
    a chain); None without stitches."""
    if stitches is None:
        return None
    if hasattr(stitches, "detach"):
        stitches = stitches.detach().cpu().numpy()
    st = np.asarray(stitches, np.int64).reshape(-1, 2)
    if len(st) == 0:
        return None
    import scipy.sparse as sp
    from scipy.sparse.csgraph import connected_components

    graph = sp.coo_matrix((np.ones(len(st)), (st[:, 0], st[:, 1])), shape=(n_vertices, n_vertices))
    return connected_components(graph, directed=False)[1].astype(np.int64)


def check_thickness(thickness: Any) -> float:
    h = float(thickness)
    if not (np.isfinite(h) and h > 0):
        raise MeshError(f"collision thickness must be a positive number of metres, got {thickness!r}")
    return h
