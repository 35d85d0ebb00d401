"""The KDSM's volume: a tetrahedral mesh of the air around the body in its rest pose.

The kinematically deforming skinned mesh (KDSM) parametrises the region where garments
live: a shell from just inside the skin to `outer` metres outside it. It is cut from a
regular lattice (cubes of edge `cell`, each split into six tetrahedra around its main
diagonal, Kuhn's subdivision, which conforms across cubes) by the body's signed distance
(tryon.sim.collision: pseudonormal sign, exact for a closed surface). A tetrahedron is
kept when some point in it can lie in the band [-inner, outer]: the signed distance is
1-Lipschitz, so a tet whose vertex distances are all above outer + diameter (or below
-inner - diameter) holds no point of the band. Every point of the band inside `bounds`
therefore lies in a kept tet; `tests/kdsm` checks this.

The rest pose is the pose the garment is draped in (tryon's A-pose): a point of the
volume is a material point, and posing the volume (tryon.kdsm.skinning) carries it.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np

from tryon.errors import TryonError

# the six tetrahedra of a cube around its diagonal 000-111: one per order of the axes
_CORNER = {bits: i for i, bits in enumerate(itertools.product((0, 1), repeat=3))}
CUBE_TETS = np.array([[_CORNER[(0, 0, 0)], *[_CORNER[tuple(int(a in order[:k + 1]) for a in range(3))] for k in range(3)]]
                      for order in itertools.permutations(range(3))], np.int64)
MAX_LATTICE_POINTS = 3_000_000


@dataclass
class TetVolume:
    """Tetrahedra [T,4] (positively oriented) over vertices [N,3] (the rest pose), each
    vertex's signed distance to the body [N] (m, negative inside) and the lattice's cell."""

    vertices: np.ndarray
    tets: np.ndarray
    distance: np.ndarray
    cell: float

    def tree(self):
        """The BVH over the rest-pose tets, built on first use and kept."""
        if getattr(self, "_tree", None) is None:
            self._tree = tet_tree(self.vertices, self.tets)
        return self._tree

    def signed_volumes(self, x: np.ndarray | None = None) -> np.ndarray:
        """Signed volume of every tet [T] at positions `x` (default: the rest pose)."""
        return tet_volumes(self.vertices if x is None else x, self.tets)

    def save(self, path) -> None:
        np.savez_compressed(path, vertices=self.vertices, tets=self.tets, distance=self.distance, cell=self.cell)

    @classmethod
    def load(cls, path) -> "TetVolume":
        d = np.load(path)
        return cls(d["vertices"], d["tets"], d["distance"], float(d["cell"]))


def tet_tree(x: np.ndarray, tets: np.ndarray):
    """The BVH over tets at positions `x` (the collision kernels; build once for a volume
    that does not move)."""
    from tryon.sim.geometry import BVH, element_boxes

    return BVH.build(*element_boxes(np.ascontiguousarray(x, np.float64), np.ascontiguousarray(tets), 1e-9))


def tet_volumes(x: np.ndarray, tets: np.ndarray) -> np.ndarray:
    a, b, c, d = (x[tets[:, k]] for k in range(4))
    return np.einsum("ij,ij->i", np.cross(b - a, c - a), d - a) / 6.0


def build_volume(body_vertices: np.ndarray, body_faces: np.ndarray, cell: float = 0.02, inner: float = 0.01,
                 outer: float = 0.10, bounds: tuple[np.ndarray, np.ndarray] | None = None) -> TetVolume:
    """The shell of air [-inner, outer] around the body (module docstring), within the box
    `bounds` = (lo [3], hi [3]) if given (e.g. where a garment can reach)."""
    from tryon.sim.geometry import signed_obstacle_distance

    body_vertices = np.asarray(body_vertices, np.float64)
    if not (0.002 <= cell <= 0.2 and 0.0 <= inner <= 0.2 and 0.0 < outer <= 0.5):
        raise TryonError(f"KDSM volume: cell {cell} m (0.002-0.2), inner {inner} m (0-0.2) and outer {outer} m (0-0.5) "
                         "are out of range")
    lo = body_vertices.min(0) - outer - cell
    hi = body_vertices.max(0) + outer + cell
    if bounds is not None:
        lo, hi = np.maximum(lo, np.asarray(bounds[0], float)), np.minimum(hi, np.asarray(bounds[1], float))
        if (hi <= lo).any():
            raise TryonError(f"KDSM volume: the bounds {np.round(bounds, 3).tolist()} do not meet the body")
    shape = np.ceil((hi - lo) / cell).astype(int) + 1
    if np.prod(shape) > MAX_LATTICE_POINTS:
        raise TryonError(f"KDSM volume: a lattice of {shape.tolist()} points at {cell} m cells is too large; use a "
                         "larger cell or tighter bounds")
    axes = [lo[k] + cell * np.arange(shape[k]) for k in range(3)]
    points = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
    distance = signed_obstacle_distance(points, body_vertices, body_faces)
    tets = _lattice_tets(shape)
    diameter = cell * np.sqrt(3.0)
    dt = distance[tets]
    keep = (dt.min(1) <= outer + diameter) & (dt.max(1) >= -inner - diameter)
    tets = tets[keep]
    used, tets = np.unique(tets, return_inverse=True)
    tets = tets.reshape(-1, 4)
    volume = TetVolume(points[used], tets, distance[used], float(cell))
    flip = volume.signed_volumes() < 0
    volume.tets[flip] = volume.tets[flip][:, [1, 0, 2, 3]]
    return volume


def _lattice_tets(shape: np.ndarray) -> np.ndarray:
    """Kuhn's six tets of every cube of a lattice of `shape` points (C order ids)."""
    nx, ny, nz = (int(s) for s in shape)
    i, j, k = np.meshgrid(np.arange(nx - 1), np.arange(ny - 1), np.arange(nz - 1), indexing="ij")
    base = (i * ny * nz + j * nz + k).reshape(-1)
    offset = np.array([a * ny * nz + b * nz + c for a, b, c in itertools.product((0, 1), repeat=3)], np.int64)
    corners = base[:, None] + offset[None]                           # [C,8]
    return corners[:, CUBE_TETS].reshape(-1, 4)
