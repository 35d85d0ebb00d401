"""The implicit-Euler step as a residual in torch, for implicit differentiation.

The forward step (`tryon.sim.integrator`) solves ``A dv = b`` with

    A = M + dt D + dt^2 H,    b = dt (f - dt H v)

(M lumped masses, H the stiffness blocks of membrane, bending, stitches and contact
penalties, D the damping blocks of wind, air, Rayleigh damping and friction, f all
forces), everything evaluated at the start of the step. Differentiating the solution
``dv(p)`` of ``r(dv, p) = b(p) - A(p) dv = 0`` with respect to any input p (positions,
velocities, fabric parameters, external forces, wind, pinned-vertex targets) gives
``dL/dp = a^T dr/dp`` with the adjoint ``A^T a = dL/d(dv)`` (one solve with the forward
factorisation, A symmetric). `step_residual` is the scalar ``a^T r(dv, p)`` with ``a``
and ``dv`` constants, written matrix-free as torch expressions of p (the same closed forms
as the forward kernels, `tryon.sim.forces` on its torch path), so that one autograd pass
returns ``a^T dr/dp`` for all inputs at once. Third derivatives (``dH/dx dv``) and the
strain / curvature dependence of the Wang 2011 stiffness lookups are included: the
gradient is the one of the discrete map the forward computes.

Friction's lagged coefficient ``c = mu fn / max(|vt|, slip speed)`` (see
`tryon.sim.forces.contact`) is differentiated with
``friction_gradient="exact"`` (the default) or held constant with ``"constant"`` (an
approximation).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from tryon.fabric.base import Fabric
from tryon.sim.forces.bending import bending_forces
from tryon.sim.forces.contact import (
    FRICTION_SLIP_SPEED,
    friction_coefficient,
    lumped_weights,
    penalty_force,
    penalty_stiffness,
)
from tryon.sim.forces.membrane import membrane_forces
from tryon.sim.forces.wind import wind_forces
from tryon.sim.integrator import ActiveContacts
from tryon.sim.model import ClothModel
from tryon.diff.geometry import contact_frame, gather_points


# --------------------------------------------------------------------------- contacts


def _per_point(values: torch.Tensor, idx: np.ndarray, is_cloth: np.ndarray) -> torch.Tensor:
    """Rows [C, 4, 3] of a per-vertex field at the cloth points (zero at obstacle points)."""
    rows = values[torch.as_tensor(np.where(is_cloth, idx, 0))]
    return rows * torch.as_tensor(is_cloth, dtype=values.dtype)[..., None]


def contact_residual(
    model: ClothModel,
    act: ActiveContacts,
    x: torch.Tensor,
    v: torch.Tensor,
    ob0: np.ndarray,
    ob1: np.ndarray,
    dt: float,
    a: torch.Tensor,
    dv: torch.Tensor,
    friction_gradient: str,
) -> torch.Tensor:
    """``a^T`` (contact part of the residual) of the penalty and friction potentials
    (`tryon.sim.forces.contact`, the laws the forward step assembles): penalty force
    ``f_k = fn w_k n`` with lumped stiffness ``stiff |w_k| sum|w| n n^T``, friction force
    ``-c w_k vt`` with lumped damping ``c |w_k| sum|w| (I - n n^T)``."""
    cs = model.collision
    c = act.contacts
    h = cs.thickness
    P = gather_points(c.idx, x, ob1)
    w, n = contact_frame(P, c.kind, c.n, c.w)
    gap = torch.einsum("ck,ckd,cd->c", w, P, n)
    depth = h - gap
    k = cs.stiffness * float(model.vertex_area.mean())
    fn = penalty_force(depth, h, k)
    stiff = penalty_stiffness(depth, h, k)
    cloth = torch.as_tensor(act.is_cloth)
    wc = torch.where(cloth, w, torch.zeros_like(w))
    lump = lumped_weights(wc)
    A = _per_point(a, c.idx, act.is_cloth)
    an = (A * n[:, None, :]).sum(-1)  # [C, 4]
    U = _per_point(dt * dt * (v + dv), c.idx, act.is_cloth)
    un = (U * n[:, None, :]).sum(-1)
    out = dt * (fn[:, None] * wc * an).sum() - (stiff[:, None] * lump * an * un).sum()
    vel_ob = (ob1 - ob0) / dt if len(ob1) else np.zeros((1, 3))
    vel = gather_points(c.idx, v, vel_ob)
    vr = torch.einsum("ck,ckd->cd", w, vel)
    vt = vr - (vr * n).sum(1, keepdim=True) * n
    mu = torch.as_tensor(act.mu, dtype=x.dtype)
    cf = friction_coefficient(mu, fn, vt.norm(dim=1).clamp_min(FRICTION_SLIP_SPEED))
    if friction_gradient == "constant":
        cf = cf.detach()
    DV = _per_point(dv, c.idx, act.is_cloth)
    dvt = DV - (DV * n[:, None, :]).sum(-1, keepdim=True) * n[:, None, :]
    friction_force = -(cf[:, None] * (wc * (A * vt[:, None, :]).sum(-1))).sum()
    friction_damping = (cf[:, None] * lump * (A * dvt).sum(-1)).sum()
    return out + dt * friction_force - dt * friction_damping


# --------------------------------------------------------------------------- the residual


@dataclass
class StepInputs:
    """Torch inputs of one step (leaves of the backward graph)."""

    x: torch.Tensor
    v: torch.Tensor
    fabric: Fabric
    external_force: torch.Tensor | None
    wind_velocity: torch.Tensor | None


def _element_bilinear(a: torch.Tensor, hess: torch.Tensor, u: torch.Tensor, elements: torch.Tensor) -> torch.Tensor:
    """sum_e a_e^T hess_e u_e for per-element blocks hess [E, 3k, 3k]."""
    ae = a[elements].reshape(len(elements), -1)
    ue = u[elements].reshape(len(elements), -1)
    return torch.einsum("ei,eij,ej->", ae, hess, ue)


def _stitch_residual(model: ClothModel, x, a, u) -> torch.Tensor:
    """Zero-length springs ``E = k/2 |x_i - x_j|^2``: ``a^T (dt f - H u)``, dt folded in u."""
    st = model.stitches
    k = model.stitch_stiffness
    if len(st) == 0 or k <= 0:
        return x.new_zeros(())
    i, j = st[:, 0], st[:, 1]
    da = a[i] - a[j]
    return -k * ((da * (x[i] - x[j])).sum() + (da * (u[i] - u[j])).sum())


def _soft_handle_residual(model: ClothModel, x: torch.Tensor, a: torch.Tensor, u: torch.Tensor, t_end: float,
                          dt: float) -> torch.Tensor:
    """Soft handles ``E = k/2 |x - target|^2``: ``a^T (dt f - H u)`` with ``u = dt^2 (v + dv)``."""
    idx, k, target = model.handle_springs(t_end)
    if len(idx) == 0:
        return x.new_zeros(())
    i = torch.from_numpy(idx)
    kk = torch.from_numpy(k)[:, None]
    return -(kk * a[i] * (dt * (x[i] - torch.from_numpy(target)) + u[i])).sum()


def step_residual(
    model: ClothModel,
    inp: StepInputs,
    dv: torch.Tensor,
    a: torch.Tensor,
    dt: float,
    contacts: ActiveContacts | None,
    ob0: np.ndarray,
    ob1: np.ndarray,
    friction_gradient: str = "constant",
    t_end: float = 0.0,
) -> torch.Tensor:
    """``a^T (dt f - dt^2 H (v + dv) - dt D dv - M dv)`` as a torch scalar (module docstring)."""
    x, v, fab = inp.x, inp.v, inp.fabric
    mass = fab.density * model.vertex_area
    if model.added_mass is not None:
        mass = mass + model.added_mass
    u_el = dt * dt * (v + dv) + dt * model.damping * dv  # Rayleigh damping D = c H (elastic part)
    _, g_mem, h_mem = membrane_forces(x, model.faces, model.Dm_inv, model.rest_area,
                                      model.stretching_law(fab.stretching_stiffness_in_strain))
    _, g_bend, h_bend = bending_forces(
        x, model.hinges, model.hinge_rest_theta, model.hinge_area_sum, model.hinge_edge_dir_uv,
        model.bending_law(fab.bending_stiffness_in_curvature),
    )
    af, ah = a[model.faces].reshape(len(model.faces), -1), a[model.hinges].reshape(len(model.hinges), -1)
    out = -dt * ((g_mem * af).sum() + (g_bend * ah).sum())
    out = out - _element_bilinear(a, h_mem, u_el, model.faces) - _element_bilinear(a, h_bend, u_el, model.hinges)
    wind_v = inp.wind_velocity if inp.wind_velocity is not None else torch.as_tensor(model.wind.velocity, dtype=x.dtype)
    f_wind, d_wind = wind_forces(x, v, model.faces, model.rest_area, wind_v, model.wind.density, model.wind.drag,
                                 with_jacobian=model.wind.implicit)
    out = out + dt * (f_wind * a).sum()
    if d_wind is not None:
        out = out - dt * _element_bilinear(a, d_wind, dv, model.faces)
    out = out + _soft_handle_residual(model, x, a, dt * dt * (v + dv), t_end, dt)
    force = mass[:, None] * model.gravity[None]
    if inp.external_force is not None:
        force = force + inp.external_force
    out = out + dt * (force * a).sum() + _stitch_residual(model, x, dt * a, u_el / dt)
    if model.air_damping > 0:
        out = out - model.air_damping * ((mass[:, None] * a) * (dt * v + dt * dv)).sum()
    out = out - ((mass[:, None] * a) * dv).sum()
    if contacts is not None and len(contacts):
        out = out + contact_residual(model, contacts, x, v, ob0, ob1, dt, a, dv, friction_gradient)
    return out
