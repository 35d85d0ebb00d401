"""One differentiable time step around the forward solver.

Forward (`TapedSolver.taped_step`): the public phases of `ImplicitEulerSolver`'s step -
contacts, assembly (forces, proximity penalties and friction), the implicit solve,
continuous collision detection and impact zones - on the fast numpy / numba path, with
the linear system factorised directly (CHOLMOD, else SuperLU) and the factorisation
kept; the step records a `StepTape` (solution, active contacts, the impact-zone
projections).

Backward (`StepFunction`), for the outputs ``x' = z`` and ``v' = (z - x) / dt``:

1. impact zones: each projection the response solved is a `ProjectionFn` (QR of the
   active constraints), chained in the order the response added constraints, with the
   constraint geometry recomputed in torch at the time of impact (`impact_frame`);
2. candidate positions ``x1 = x + dt (v + dv)`` (pinned vertices: their targets);
3. the implicit solve: one adjoint solve ``A a = dL/d(dv)`` with the kept factorisation,
   then one autograd pass through the residual ``a^T r(dv, p)`` (`step_residual`) gives
   the gradients for positions, velocities, fabric parameters, external forces, wind and
   pinned-vertex targets.

A step whose response falls back to rigid impact zones (the last resort after
substepping) is differentiated as if the response were the identity; `StepTape.fallback`
flags it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np
import torch

from tryon.errors import SimulationError
from tryon.fabric.base import Fabric
from tryon.sim.collision import Contacts
from tryon.sim.integrator import ActiveContacts, ImplicitEulerSolver, StepOptions
from tryon.sim.linear import HAVE_CHOLMOD
from tryon.sim.model import ClothModel, ClothState, Control
from tryon.diff.geometry import impact_frame
from tryon.diff.qp import Projection, ProjectionFn
from tryon.diff.terms import StepInputs, step_residual

FRICTION_GRADIENTS = ("constant", "exact")
QP_METHODS = ("qr", "kkt")


@dataclass
class StepTape:
    """What the backward pass of one (sub)step needs from its forward pass."""

    t0: float
    dt: float
    ok: bool
    x: np.ndarray
    dv: np.ndarray | None = None
    solve: Callable | None = None
    x_cand: np.ndarray | None = None
    z: np.ndarray | None = None
    v_new: np.ndarray | None = None
    contacts: ActiveContacts | None = None
    ob0: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    ob1: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    trace: list = field(default_factory=list)
    constraints: Contacts = field(default_factory=Contacts.empty)
    target_gap: float = 0.0
    fallback: bool = False
    impacts: int = 0


class TapedSolver:
    """Records differentiable steps of an `ImplicitEulerSolver` by composing its public
    phases (`detect_contacts`, `assemble`, a direct `solve_factorized` that keeps the
    factorisation for the adjoint, `respond` with the impact-zone trace)."""

    def __init__(self, model: ClothModel, options: StepOptions | None = None, fabric: Fabric | None = None):
        options = options or StepOptions()
        direct = StepOptions(linear_solver="cholmod" if HAVE_CHOLMOD else "splu", pcg_tol=options.pcg_tol,
                             max_substep_depth=options.max_substep_depth, collisions=options.collisions)
        self.solver = ImplicitEulerSolver(model, direct, fabric)

    @property
    def model(self) -> ClothModel:
        return self.solver.model

    @property
    def options(self) -> StepOptions:
        return self.solver.options

    @property
    def pinned_mask(self) -> np.ndarray:
        return self.solver.pinned_mask

    @property
    def mass(self) -> np.ndarray:
        return self.solver.mass

    def set_fabric(self, fabric: Fabric) -> None:
        """Use `fabric` (its detached values) from the next step on: stiffness and masses."""
        self.solver.use_fabric(fabric)

    def taped_step(self, x: np.ndarray, v: np.ndarray, t0: float, dt: float, force: np.ndarray | None,
                   wind: np.ndarray | None, targets: np.ndarray, allow_fallback: bool) -> StepTape:
        """One step from (x, v) at t0 (numpy in, tape out): the forward solver's phases with
        a direct solve whose factorisation is kept. (`targets`, the pinned vertices' end
        positions, may differ from the model's handles: a policy can move them.)"""
        solver, m = self.solver, self.solver.model
        tape = StepTape(t0=t0, dt=dt, ok=False, x=x, ob0=m.obstacles.vertices_at(t0), ob1=m.obstacles.vertices_at(t0 + dt))
        state = ClothState(torch.from_numpy(x), torch.from_numpy(v), t0)
        control = Control(None if force is None else torch.from_numpy(force), None if wind is None else torch.from_numpy(wind))
        contacts = solver.detect_contacts(x, tape.ob1)
        system = solver.assemble(state, dt, control, contacts, tape.ob0, tape.ob1)
        system.targets = targets
        system.fixed_dv = (targets - x[solver.pinned_mask]) / dt - v[solver.pinned_mask]
        tape.contacts = system.contacts
        dv, tape.solve = solver.linear.solve_factorized(system.A, system.rhs, solver.pinned_mask, system.fixed_dv)
        if not np.all(np.isfinite(dv)):
            return tape
        x_new, _ = solver.candidate(system, dv, dt)
        tape.dv, tape.x_cand = dv, x_new
        if solver.options.collisions and m.collision.enabled:
            trace: list = []
            x_new, ok, report = solver.respond(x, x_new, tape.ob0, tape.ob1, allow_fallback, trace=trace)
            tape.trace, tape.fallback = trace, report.fallback
            tape.constraints, tape.target_gap, tape.impacts = report.constraints, report.target_gap, report.impacts_found
            if not ok:
                return tape
        tape.z, tape.v_new, tape.ok = x_new, (x_new - x) / dt, True
        return tape


# --------------------------------------------------------------------------- backward


@dataclass
class StepContext:
    """Fixed data the backward pass of every step shares."""

    solver: TapedSolver
    fabric_template: Fabric
    friction_gradient: str = "exact"
    qp_method: str = "qr"


def response_backward(ctx: StepContext, tape: StepTape, gz: np.ndarray):
    """dL/dx1, dL/dx0 and dL/dmass of the impact-zone response for dL/dz (module docstring)."""
    if not tape.trace:
        return gz, np.zeros_like(gz), np.zeros(len(gz))
    solver = ctx.solver
    free = ~solver.pinned_mask
    with torch.enable_grad():
        x0 = torch.from_numpy(tape.x).requires_grad_()
        x1 = torch.from_numpy(tape.x_cand).requires_grad_()
        mass = torch.from_numpy(solver.mass).requires_grad_()
        against = x1
        ws, ns = [], []
        start = 0
        for _, n_new, qp in tape.trace:
            found = tape.constraints.select(np.arange(start, start + n_new))
            w, n = impact_frame(found, x0, against, tape.ob0, tape.ob1)
            ws.append(w)
            ns.append(n)
            start += n_new
            proj = Projection(tape.constraints.idx[:start], qp.z, qp.lam, free, tape.ob1, tape.target_gap, ctx.qp_method)
            against = ProjectionFn.apply(x1, mass, torch.cat(ws), torch.cat(ns), proj)
        g0, g1, gm = torch.autograd.grad(against, [x0, x1, mass], torch.from_numpy(gz), allow_unused=True)
    as_np = lambda g, like: like if g is None else g.numpy()  # noqa: E731
    return as_np(g1, np.zeros_like(gz)), as_np(g0, np.zeros_like(gz)), as_np(gm, np.zeros(len(gz)))


def step_backward(ctx: StepContext, tape: StepTape, inputs: tuple, g_xnew: torch.Tensor | None, g_vnew: torch.Tensor | None):
    """Gradients for (x, v, params, force, wind, targets) of one step (module docstring)."""
    x, v, params, force, wind, targets = inputs
    solver, dt = ctx.solver, tape.dt
    pinned = solver.pinned_mask
    free = ~pinned
    gxn = np.zeros_like(tape.x) if g_xnew is None else g_xnew.detach().numpy()
    gvn = np.zeros_like(tape.x) if g_vnew is None else g_vnew.detach().numpy()
    gz = gxn + gvn / dt
    g_x1, g_x_col, g_mass = (gz, 0.0, None) if tape.fallback else response_backward(ctx, tape, gz)
    g_x = -gvn / dt + g_x_col + np.where(free[:, None], g_x1, 0.0)
    g_v = np.where(free[:, None], dt * g_x1, 0.0)
    rhs = np.where(free[:, None], dt * g_x1, 0.0)
    a = np.asarray(tape.solve(rhs.reshape(-1))).reshape(-1, 3)
    a[pinned] = 0.0
    with torch.enable_grad():
        leaves = [t.detach().requires_grad_() if t is not None else None for t in (x, v, params, force, wind, targets)]
        xl, vl, pl, fl, wl, tl = leaves
        fabric = ctx.fabric_template.with_parameters(pl)
        dv = torch.from_numpy(tape.dv.copy())
        pin_idx = torch.from_numpy(np.flatnonzero(pinned))
        if len(pin_idx):
            target_t = tl if tl is not None else torch.from_numpy(tape.x_cand[pinned])
            dv = dv.index_put((pin_idx,), (target_t - xl[pin_idx]) / dt - vl[pin_idx])
        S = step_residual(solver.model, StepInputs(xl, vl, fabric, fl, wl), dv, torch.from_numpy(a), dt,
                          tape.contacts, tape.ob0, tape.ob1, ctx.friction_gradient, t_end=tape.t0 + dt)
        if g_mass is not None:
            S = S + (torch.from_numpy(g_mass) * fabric.density * solver.model.vertex_area).sum()
        want = [t for t in leaves if t is not None]
        grads = dict(zip(map(id, want), torch.autograd.grad(S, want, allow_unused=True)))
    out = []
    extra = {0: g_x, 1: g_v}
    for i, leaf in enumerate(leaves):
        if leaf is None:
            out.append(None)
            continue
        g = grads[id(leaf)]
        g = torch.zeros_like(leaf) if g is None else g.detach()
        if i in extra:
            g = g + torch.from_numpy(extra[i])
        if i == 5:
            g = g + torch.from_numpy(g_x1[pinned])
        out.append(g)
    return tuple(out)


class StepFunction(torch.autograd.Function):
    """(x, v, params, force, wind, targets) -> (x', v') for a step already run forward
    (the tape); backward is `step_backward`."""

    @staticmethod
    def forward(ctx, step_ctx: StepContext, tape: StepTape, x, v, params, force, wind, targets):
        ctx.step_ctx, ctx.tape = step_ctx, tape
        ctx.save_for_backward(x, v, params, force, wind, targets)
        return torch.from_numpy(tape.z.copy()), torch.from_numpy(tape.v_new.copy())

    @staticmethod
    def backward(ctx, g_x, g_v):
        grads = step_backward(ctx.step_ctx, ctx.tape, ctx.saved_tensors, g_x, g_v)
        return (None, None) + grads


def _as_np(t: torch.Tensor | None) -> np.ndarray | None:
    return None if t is None else np.ascontiguousarray(t.detach().numpy(), dtype=np.float64)


def differentiable_step(step_ctx: StepContext, x: torch.Tensor, v: torch.Tensor, params: torch.Tensor, t0: float,
                        dt: float, force: torch.Tensor | None, wind: torch.Tensor | None,
                        targets: Callable[[float, torch.Tensor], torch.Tensor], depth: int = 0, tapes: list | None = None):
    """(x', v') after one step of length dt from t0, as a differentiable function of x, v,
    params, force, wind and the pinned targets (`targets(t, x)` gives them at time t).
    A step whose collision response fails is split in two halves (up to
    ``2^max_substep_depth`` substeps, as the forward solver does)."""
    solver = step_ctx.solver
    tgt = targets(t0 + dt, x)
    max_depth = solver.options.max_substep_depth
    tape = solver.taped_step(_as_np(x), _as_np(v), t0, dt, _as_np(force), _as_np(wind), _as_np(tgt), depth >= max_depth)
    if tape.ok:
        if tapes is not None:
            tapes.append(tape)
        pinned_t = tgt if solver.pinned_mask.any() else None
        return StepFunction.apply(step_ctx, tape, x, v, params, force, wind, pinned_t)
    if depth >= max_depth:
        raise SimulationError(f"differentiable step at t={t0:.4f}s failed even with {2 ** depth} substeps; reduce dt")
    mid_x, mid_v = differentiable_step(step_ctx, x, v, params, t0, dt / 2, force, wind, targets, depth + 1, tapes)
    return differentiable_step(step_ctx, mid_x, mid_v, params, t0 + dt / 2, dt / 2, force, wind, targets, depth + 1, tapes)
