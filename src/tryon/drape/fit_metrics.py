"""Numbers that say how a garment fits: strain, contact pressure, penetration, energy.

* strain per face: largest principal stretch of the deformation gradient minus one
  (0.05 = stretched 5 % along its most stretched direction);
* contact pressure per vertex: the repulsion force the body applies (the simulator's
  contact penalty at the final state) over the vertex's rest area, in Pa;
* penetration: garment vertices inside the body (signed distance below zero), as a
  percentage of all garment vertices, and edge-triangle intersections;
* potential energy: membrane + bending + gravity (J, gravity measured from the floor).
"""

from __future__ import annotations

import numpy as np
import torch

from tryon.sim import geometry as geo
from tryon.sim.forces.bending import bending_forces
from tryon.sim.forces.membrane import membrane_forces
from tryon.sim.metrics import principal_stretch


def face_strain(model, x: np.ndarray) -> np.ndarray:
    return (principal_stretch(torch.from_numpy(np.ascontiguousarray(x)), model.faces, model.Dm_inv) - 1.0).numpy()


def contact_pressure(solver, x: np.ndarray, t: float) -> np.ndarray:
    f = solver.obstacle_contact_forces(np.ascontiguousarray(x), t)
    return np.linalg.norm(f, axis=1) / solver.model.vertex_area.numpy()


def potential_energy(model, x: np.ndarray) -> dict[str, float]:
    xt = torch.from_numpy(np.ascontiguousarray(x))
    fab = model.fabric
    with torch.no_grad():
        e_mem, _, _ = membrane_forces(xt, model.faces, model.Dm_inv, model.rest_area, model.stretching_law(fab.stretching_stiffness),
                                      with_hessian=False)
        e_bend, _, _ = bending_forces(xt, model.hinges, model.hinge_rest_theta, model.hinge_area_sum, model.hinge_edge_dir_uv,
                                      model.bending_law(fab.bending_stiffness), with_hessian=False)
    mass = model.mass().numpy()
    e_grav = float(-(mass[:, None] * model.gravity.numpy()[None] * x).sum())
    return {"membrane_J": float(e_mem.sum()), "bending_J": float(e_bend.sum()), "gravity_J": e_grav,
            "total_J": float(e_mem.sum() + e_bend.sum()) + e_grav}


def penetration(x: np.ndarray, body_vertices: np.ndarray, body_faces: np.ndarray) -> dict[str, float]:
    d, _, _ = geo.nearest_surface_points(x, body_vertices, body_faces)
    inside = d < 0
    return {"penetration_pct": 100.0 * float(inside.mean()), "vertices_inside": int(inside.sum()),
            "deepest_penetration_mm": float(max(0.0, -d.min()) * 1000.0), "min_skin_distance_mm": float(d.min() * 1000.0),
            "mean_skin_distance_mm": float(d.mean() * 1000.0)}


def drape_metrics(result, solver, body_shift: np.ndarray | None = None) -> dict:
    """Fit numbers of a drape; `body_shift` (m): where the solver's body lies relative to
    the person (`simulate_drape` morphs the body without its overall move)."""
    model = solver.model
    x = result.x
    strain = face_strain(model, x)
    pressure = contact_pressure(solver, x - (0.0 if body_shift is None else body_shift), float(result.frame_times[-1]))
    pen = penetration(x, result.body_vertices, result.body_faces)
    n_self, n_body = geo.count_intersections(x, model.faces.numpy(), model.edges.numpy(), result.body_vertices,
                                             result.body_faces, solver.model.obstacles.edges)
    area = model.rest_area.numpy()
    result.strain = strain
    result.pressure = pressure
    return {
        "max_strain": float(strain.max()),
        "mean_strain": float((strain * area).sum() / area.sum()),
        "strain_p95": float(np.percentile(strain, 95)),
        "overstrained_area_pct": 100.0 * float(area[strain > 0.10].sum() / area.sum()),
        "max_contact_pressure_pa": float(pressure.max()),
        "mean_contact_pressure_pa": float(pressure[pressure > 0].mean()) if (pressure > 0).any() else 0.0,
        "contact_area_pct": 100.0 * float((pressure > 0).mean()),
        **pen,
        "self_intersections": int(n_self),
        "body_intersections": int(n_body),
        "potential_energy": potential_energy(model, x),
    }
