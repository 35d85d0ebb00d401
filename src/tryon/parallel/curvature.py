"""Popping error at segment boundaries: relative curvature error (Liang & Lin, SCA 2018,
Sec. 6), summed over adjacent face pairs (hinges):

    e = sum_h |kappa_h(x) - kappa_h(x_serial)| / sum_h |kappa_h(x_serial)|,

with kappa_h = 3 theta_h |e_h| / (A0 + A1) the discrete mean curvature of a hinge (signed
dihedral angle theta, rest edge length |e_h| and rest areas A0, A1 of its two faces, as in
the discrete-shells bending energy of Grinspun et al. 2003)."""

from __future__ import annotations

import numpy as np
import torch

from tryon.errors import SimulationError
from tryon.sim.forces.bending import dihedral_angle
from tryon.sim.model import ClothModel


def hinge_curvature(model: ClothModel, x: np.ndarray) -> np.ndarray:
    """Signed discrete mean curvature kappa_h [H] (1/m) of every interior edge."""
    xt = torch.from_numpy(np.array(x, dtype=np.float64))
    theta = dihedral_angle(xt, model.hinges).numpy()
    length = np.linalg.norm(model.hinge_edge_dir_uv.numpy(), axis=1)
    return 3.0 * theta * length / model.hinge_area_sum.numpy()


def relative_curvature_error(model: ClothModel, x: np.ndarray, x_reference: np.ndarray) -> float:
    """sum |kappa(x) - kappa(x_ref)| / sum |kappa(x_ref)| over the hinges of `model`."""
    k = hinge_curvature(model, x)
    k_ref = hinge_curvature(model, x_reference)
    denom = float(np.abs(k_ref).sum())
    if denom <= 0.0:
        raise SimulationError("the reference cloth is flat (zero total curvature); the relative curvature error is undefined")
    return float(np.abs(k - k_ref).sum() / denom)
