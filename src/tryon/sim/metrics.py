"""Quality numbers of a cloth state: strain, penetration, distances, energies."""

from __future__ import annotations

import numpy as np
import torch

from tryon.sim import collision as col

from tryon.sim import geometry as geo
from tryon.sim.model import ClothModel


def principal_stretch(x: torch.Tensor, faces: torch.Tensor, Dm_inv: torch.Tensor) -> torch.Tensor:
    """Largest principal stretch lambda_max [F] of each triangle (sqrt of the largest
    eigenvalue of C = F^T F, F the material-to-world deformation gradient)."""
    d1 = x[faces[:, 1]] - x[faces[:, 0]]
    d2 = x[faces[:, 2]] - x[faces[:, 0]]
    Ds = torch.stack([d1, d2], dim=2)  # [F,3,2]
    F = Ds @ Dm_inv
    C = F.transpose(1, 2) @ F
    a, b, c = C[:, 0, 0], C[:, 0, 1], C[:, 1, 1]
    mean = 0.5 * (a + c)
    rad = torch.sqrt(torch.clamp(0.25 * (a - c) ** 2 + b * b, min=0.0))
    return torch.sqrt(torch.clamp(mean + rad, min=0.0))


def face_strain(model: ClothModel, x: torch.Tensor) -> torch.Tensor:
    """Per-face strain lambda_max - 1 (0.05 means stretched by 5 %)."""
    return principal_stretch(x, model.faces, model.Dm_inv) - 1.0


def state_metrics(model: ClothModel, x: np.ndarray, t: float) -> dict:
    """Strain, intersections and obstacle distance of cloth positions x at time t."""
    xt = torch.from_numpy(np.ascontiguousarray(x))
    strain = face_strain(model, xt)
    ob = model.obstacles.vertices_at(t)
    faces = model.faces.numpy()
    edges = model.edges.numpy()
    n_self, n_obst = geo.count_intersections(
        x, faces, edges, ob, model.obstacles.faces, model.obstacles.edges, self_collision=model.collision.self_collision,
        alias=col.stitch_alias(model.stitches, len(x)),
    )
    dist = geo.min_obstacle_distance(x, ob, model.obstacles.faces) if len(ob) else float("inf")
    return {
        "max_strain": float(strain.max()),
        "mean_strain": float(strain.mean()),
        "self_intersections": int(n_self),
        "obstacle_intersections": int(n_obst),
        "min_obstacle_distance": float(dist),
    }
