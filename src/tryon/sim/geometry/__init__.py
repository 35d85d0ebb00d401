"""Geometry of triangle meshes, below the simulator and shared by everything above it:
bounding volume hierarchies and their overlap queries, normals, and the discrete queries
of a configuration (edge-triangle intersections, nearest surface points and signed
distances, pushing points out of a surface). Numba kernels (cache=True) on checked inputs;
the queries run on numba's threads with results that do not depend on their number.

Import the public names from here (`from tryon.sim.geometry import BVH, push_outside`);
the modules are the package's own business:
- `bvh`: linear BVHs over boxes, refit, pair and nearest queries;
- `normals`: face, vertex and pseudo-normals, mesh edges;
- `queries`: intersections, distances, nearest points, `push_outside`;
- `primitives`: closest points and intersection tests on 3-tuples;
- `inputs`: the checks every query makes of its arrays;
- `threads`: the fixed chunks that spread a query over the threads.
"""

from tryon.sim.geometry.bvh import BVH, element_boxes, overlapping_pairs, point_boxes
from tryon.sim.geometry.normals import area_vertex_normals, face_normals, mesh_edges, vertex_normals
from tryon.sim.geometry.queries import (
    count_intersections,
    edge_face_intersections,
    min_obstacle_distance,
    nearest_surface_locations,
    nearest_surface_points,
    push_outside,
    signed_obstacle_distance,
)

__all__ = [
    "BVH",
    "area_vertex_normals",
    "count_intersections",
    "edge_face_intersections",
    "element_boxes",
    "face_normals",
    "mesh_edges",
    "min_obstacle_distance",
    "nearest_surface_locations",
    "nearest_surface_points",
    "overlapping_pairs",
    "point_boxes",
    "push_outside",
    "signed_obstacle_distance",
    "vertex_normals",
]
