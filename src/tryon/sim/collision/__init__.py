"""Collision detection and response for cloth against itself and one kinematic obstacle
soup (ARCSim-style: Narain et al. 2012; Bridson, Fedkiw & Anderson 2002; Harmon et al. 2008).

Per time step the simulator calls
1. `find_proximities` at the start positions: contacts closer than the thickness, for the
   repulsion penalty and friction inside the implicit solve;
2. `resolve_collisions` on the solve's candidate end positions: continuous collision
   detection and impact-zone projection so that the step ends free of intersections;
3. `rigid_impact_zone_fallback` when that fails even after substepping.

All contacts share one representation (`Contacts`): four point ids, weights summing to
zero and a unit normal, gap d = sum_k w_k n . p_k. Kernels are numba-compiled (cache=True).
The geometry it is built on (BVHs, normals, intersection counts, nearest points,
`push_outside`) is `tryon.sim.geometry`.
"""

from tryon.sim.collision.ccd import find_impacts
from tryon.sim.collision.contacts import (
    EE_OBSTACLE,
    EE_SELF,
    FV_OBSTACLE,
    KIND_NAMES,
    VF_OBSTACLE,
    VF_SELF,
    Contacts,
    stitch_alias,
)
from tryon.sim.collision.impact_zones import CollisionReport, resolve_collisions, rigid_impact_zone_fallback
from tryon.sim.collision.proximity import find_proximities
from tryon.sim.collision.qp import QPResult, solve_projection
from tryon.sim.collision.scene import CollisionScene

__all__ = [
    "CollisionReport",
    "CollisionScene",
    "Contacts",
    "EE_OBSTACLE",
    "EE_SELF",
    "FV_OBSTACLE",
    "KIND_NAMES",
    "VF_OBSTACLE",
    "VF_SELF",
    "find_impacts",
    "find_proximities",
    "QPResult",
    "solve_projection",
    "stitch_alias",
    "resolve_collisions",
    "rigid_impact_zone_fallback",
]
