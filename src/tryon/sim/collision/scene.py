"""The collision scene: what collision handling needs of a cloth and its obstacles besides
their positions, travelling as one object through the Python side of `tryon.sim.collision`
(the numba kernels take the arrays flat)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from tryon.sim.collision.contacts import check_thickness, stitch_alias
from tryon.sim.collision.topology import TreeCache


@dataclass(frozen=True)
class CollisionScene:
    """Cloth topology (faces [F,3], edges [E,2]), vertex masses [N] (kg) and pinned mask
    [N], the obstacles' merged topology (ob_faces, ob_edges), the contact thickness (m) and
    whether the cloth collides with itself; `alias`: one id per cloth vertex, shared by
    stitched vertices, which contact handling treats as one vertex (None: no stitches);
    `trees`: the scene's own BVH topology cache (see `TreeCache`): a scene, and so a
    simulation, gives the same contacts whatever other scenes query in the process."""

    faces: np.ndarray
    edges: np.ndarray
    masses: np.ndarray
    pinned: np.ndarray
    ob_faces: np.ndarray
    ob_edges: np.ndarray
    thickness: float
    self_collision: bool = True
    alias: np.ndarray | None = None
    trees: TreeCache = field(default_factory=TreeCache, compare=False, repr=False)

    @classmethod
    def of(cls, faces: Any, edges: Any, masses: Any, ob_faces: Any = None, ob_edges: Any = None,
           thickness: float = 0.005, pinned_mask: Any = None, self_collision: bool = True,
           stitches: Any = None) -> "CollisionScene":
        """A scene from numpy or torch arrays (no obstacles when ob_faces is None); stitched
        vertex pairs [S,2] are one vertex to contact handling."""
        def arr(a: Any, dtype, shape: tuple) -> np.ndarray:
            if a is None:
                return np.zeros(shape, dtype)
            if hasattr(a, "detach"):
                a = a.detach().cpu().numpy()
            return np.ascontiguousarray(np.asarray(a, dtype))

        masses = arr(masses, np.float64, (0,))
        pinned = np.zeros(len(masses), bool) if pinned_mask is None else arr(pinned_mask, bool, (0,)).reshape(-1)
        return cls(arr(faces, np.int64, (0, 3)), arr(edges, np.int64, (0, 2)), masses, pinned,
                   arr(ob_faces, np.int64, (0, 3)), arr(ob_edges, np.int64, (0, 2)), check_thickness(thickness),
                   bool(self_collision), stitch_alias(stitches, len(masses)))

    def proximities(self, x: np.ndarray, ob: np.ndarray, self_collision: bool | None = None):
        """Contacts within the thickness at positions x, obstacles at ob (`find_proximities`)."""
        from tryon.sim.collision.proximity import find_proximities

        return find_proximities(x, self.faces, self.edges, ob, self.ob_faces, self.ob_edges, self.thickness,
                                self_collision=self.self_collision if self_collision is None else self_collision,
                                alias=self.alias, trees=self.trees)
