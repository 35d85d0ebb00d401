"""Implicit (backward) Euler with one Newton step per time step (Baraff & Witkin 1998),
ARCSim-style contact handling (Narain et al. 2012):

1. proximity contacts within the thickness at the start of the step become repulsion
   penalties and Coulomb friction inside the implicit solve;
2. (M + dt D + dt^2 H) dv = dt (f - dt H v), H the (PSD) stiffness of elastic and contact
   energies, D the damping of wind, friction and Rayleigh damping; pinned vertices follow
   their handles exactly;
3. continuous collision detection and impact zones turn the candidate positions into
   intersection-free ones; a step whose response fails, or that produces NaN, is retried
   with substeps, and the rigid impact-zone fail-safe is the last resort.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
import torch

from tryon.errors import SimulationError
from tryon.fabric.base import Fabric
from tryon.sim import collision as col
from tryon.sim.forces.bending import bending_forces
from tryon.sim.forces.membrane import membrane_forces
from tryon.sim.forces.wind import wind_forces
from tryon.sim.linear import BlockPattern, LinearSolver, add_diagonal_blocks, bsr_matvec, scatter_element_blocks
from tryon.sim.model import ClothModel, ClothState, Control

# relative tangential speed (m/s) below which friction turns from Coulomb's constant force
# into viscous sticking: a resting contact creeps at most this fast
FRICTION_SLIP_SPEED = 1e-3


@dataclass
class StepOptions:
    linear_solver: str = "auto"
    pcg_tol: float = 1e-4
    max_substep_depth: int = 3  # a failing step is split in 2, 4, 8 substeps
    collisions: bool = True
    max_speed: float = 50.0  # m/s: a solve that flings cloth faster has failed (retried with substeps)


@dataclass
class StepStats:
    substeps: int = 0
    contacts: int = 0
    impacts: int = 0
    collision_iterations: int = 0
    solver_iterations: int = 0
    retried: bool = False
    fallback: bool = False
    seconds: dict = field(default_factory=lambda: {"forces": 0.0, "solve": 0.0, "collision": 0.0})

    def merge(self, other: "StepStats") -> None:
        self.substeps += other.substeps
        self.contacts += other.contacts
        self.impacts += other.impacts
        self.collision_iterations += other.collision_iterations
        self.solver_iterations += other.solver_iterations
        self.retried |= other.retried
        self.fallback |= other.fallback
        for k, v in other.seconds.items():
            self.seconds[k] += v


class ImplicitEulerSolver:
    """Advances a `ClothState` of a `ClothModel`; `step` is the only place time advances."""

    def __init__(self, model: ClothModel, options: StepOptions | None = None, fabric: Fabric | None = None):
        self.model = model
        self.options = options or StepOptions()
        self.fabric = fabric or model.fabric
        faces = model.faces.numpy()
        hinges = model.hinges.numpy()
        self._stitches = model.stitches.numpy()
        self.pattern = BlockPattern(model.num_vertices, [faces, hinges, self._stitches.reshape(-1, 2)])
        self.linear = LinearSolver(self.pattern, self.options.linear_solver, tol=self.options.pcg_tol)
        self.mass = model.mass(self.fabric).detach().numpy().astype(np.float64)
        self.pinned_mask = np.zeros(model.num_vertices, dtype=bool)
        self.pinned_mask[model.pinned.numpy()] = True
        self._mass_blocks = self.mass[:, None, None] * np.eye(3)[None]
        self._faces_np = faces
        self._edges_np = model.edges.numpy()
        self._last_dv: np.ndarray | None = None
        self.last_collision: col.CollisionReport | None = None  # the latest response's report, for diagnoses

    # ------------------------------------------------------------------ public API
    def step(self, state: ClothState, dt: float, control: Control | None = None) -> tuple[ClothState, StepStats]:
        """One time step of length dt; retried with substeps when it fails."""
        if dt <= 0:
            raise SimulationError(f"time step must be positive, got dt={dt}")
        stats = StepStats()
        out = self._advance_with_retries(state, dt, control, 0, stats)
        return out, stats

    # ------------------------------------------------------------------ internals
    def _advance_with_retries(self, state, dt, control, depth, stats) -> ClothState:
        new, ok, sub = self._advance(state, dt, control, allow_fallback=depth >= self.options.max_substep_depth)
        stats.merge(sub)
        if ok:
            return new
        if depth >= self.options.max_substep_depth:
            raise SimulationError(
                f"time step at t={state.t:.4f}s failed even with {2 ** depth} substeps; reduce dt or "
                f"check the scene for cloth starting inside an obstacle"
            )
        stats.retried = True
        mid = self._advance_with_retries(state, dt / 2, control, depth + 1, stats)
        return self._advance_with_retries(mid, dt / 2, control, depth + 1, stats)

    def _advance(self, state: ClothState, dt: float, control: Control | None, allow_fallback: bool):
        m = self.model
        stats = StepStats(substeps=1)
        x = state.x.detach().numpy()
        v = state.v.detach().numpy()
        t0, t1 = state.t, state.t + dt
        ob0 = m.obstacles.vertices_at(t0)
        ob1 = m.obstacles.vertices_at(t1)

        tic = time.perf_counter()
        H, D, f = self._elastic_and_air(state, control)
        contacts = self._proximity(x, ob1)
        stats.contacts = 0 if contacts is None else len(contacts)
        active = self._add_contact_terms(contacts, x, v, ob1, H, f) if stats.contacts else None
        if active is not None:
            self._add_friction_terms(active, v, ob0, ob1, dt, D, f)
        stats.seconds["forces"] = time.perf_counter() - tic

        tic = time.perf_counter()
        A = dt * dt * H + dt * D
        A[self.pattern.diag_block] += self._mass_blocks
        Hv = np.zeros_like(v)
        bsr_matvec(self.pattern.indptr, self.pattern.indices, H, v, Hv)
        rhs = dt * (f - dt * Hv)
        targets = m.pin_targets(t1).numpy()
        fixed_dv = (targets - x[self.pinned_mask]) / dt - v[self.pinned_mask]
        dv = self.linear.solve(A, rhs, self.pinned_mask, fixed_dv, guess=self._last_dv)
        stats.solver_iterations = self.linear.last_iterations
        stats.seconds["solve"] = time.perf_counter() - tic
        if not np.all(np.isfinite(dv)):
            return state, False, stats

        v_new = v + dv
        speed = np.linalg.norm(v_new, axis=1)
        if speed.max() > self.options.max_speed:
            if not allow_fallback:
                return state, False, stats
            # last resort: cap the runaway velocities so the fail-safe gets a sane candidate
            stats.fallback = True
            v_new *= np.minimum(1.0, self.options.max_speed / np.maximum(speed, 1e-300))[:, None]
        x_new = x + dt * v_new
        x_new[self.pinned_mask] = targets

        tic = time.perf_counter()
        ok = True
        if self.options.collisions and m.collision.enabled:
            x_new, ok = self._respond(x, x_new, ob0, ob1, stats, allow_fallback)
        stats.seconds["collision"] = time.perf_counter() - tic
        if not ok:
            return state, False, stats
        self._last_dv = dv
        v_new = (x_new - x) / dt
        return ClothState(torch.from_numpy(x_new), torch.from_numpy(v_new), t1), True, stats

    def _elastic_and_air(self, state: ClothState, control: Control | None):
        """Stiffness blocks H, damping blocks D and total force f [N,3] (numpy)."""
        m, fab = self.model, self.fabric
        x, v = state.x, state.v
        H = self.pattern.zeros()
        D = self.pattern.zeros()
        with torch.no_grad():
            _, g_mem, h_mem = membrane_forces(x, m.faces, m.Dm_inv, m.rest_area, fab.stretching_stiffness)
            _, g_bend, h_bend = bending_forces(
                x, m.hinges, m.hinge_rest_theta, m.hinge_area_sum, m.hinge_edge_dir_uv, fab.bending_stiffness
            )
            wind_v = m.wind.velocity if control is None or control.wind_velocity is None else control.wind_velocity
            f_wind, d_wind = wind_forces(
                x, v, m.faces, m.rest_area, torch.as_tensor(wind_v, dtype=x.dtype), m.wind.density, m.wind.drag
            )
        n = m.num_vertices
        f = -_scatter_vertex_grad(g_mem.numpy(), self._faces_np, n) - _scatter_vertex_grad(g_bend.numpy(), m.hinges.numpy(), n)
        f += f_wind.numpy()
        f += self.mass[:, None] * m.gravity.numpy()[None]
        if control is not None and control.external_force is not None:
            f += control.external_force.detach().numpy()
        scatter_element_blocks(H, self.pattern.element_maps[0], np.ascontiguousarray(h_mem.numpy()), 3)
        scatter_element_blocks(H, self.pattern.element_maps[1], np.ascontiguousarray(h_bend.numpy()), 4)
        if d_wind is not None:
            scatter_element_blocks(D, self.pattern.element_maps[0], np.ascontiguousarray(d_wind.numpy()), 3)
        if len(self._stitches) and m.stitch_stiffness > 0:
            self._add_stitches(x.numpy(), f, H)
        if m.damping > 0:
            D += m.damping * H
        if m.air_damping > 0:
            D[self.pattern.diag_block] += m.air_damping * self._mass_blocks
            f -= m.air_damping * self.mass[:, None] * v.numpy()
        return H, D, f

    def _add_stitches(self, x: np.ndarray, f: np.ndarray, H: np.ndarray) -> None:
        """Zero-length springs E = k/2 |x_i - x_j|^2 between stitched vertices (sewing)."""
        k = self.model.stitch_stiffness
        i, j = self._stitches[:, 0], self._stitches[:, 1]
        pull = k * (x[i] - x[j])
        np.add.at(f, i, -pull)
        np.add.at(f, j, pull)
        block = k * np.kron(np.array([[1.0, -1.0], [-1.0, 1.0]]), np.eye(3))
        hess = np.ascontiguousarray(np.broadcast_to(block, (len(i), 6, 6)))
        scatter_element_blocks(H, self.pattern.element_maps[2], hess, 2)

    def obstacle_contact_forces(self, x: np.ndarray, t: float) -> np.ndarray:
        """Repulsion force [N,3] the obstacles apply to each cloth vertex at positions x
        (the penalty of step 3 at rest; divide by vertex area for contact pressure)."""
        m = self.model
        ob = m.obstacles.vertices_at(t)
        f = np.zeros_like(x)
        if len(ob) == 0:
            return f
        c = col.find_proximities(x, self._faces_np, self._edges_np, ob, m.obstacles.faces, m.obstacles.edges,
                                 m.collision.thickness, self_collision=False)
        if len(c):
            self._add_contact_terms(c, x, np.zeros_like(x), ob, self.pattern.zeros(), f)
        return f

    def _proximity(self, x: np.ndarray, ob1: np.ndarray):
        m = self.model
        if not (self.options.collisions and m.collision.enabled):
            return None
        return col.find_proximities(
            x, self._faces_np, self._edges_np, ob1, m.obstacles.faces, m.obstacles.edges,
            m.collision.thickness, self_collision=m.collision.self_collision,
        )

    def _add_contact_terms(self, c, x, v, ob1, H, f):
        """Cubic repulsion penalty E = k (h - g)^3 / (6h) on every contact gap g < h
        (ARCSim's proximity constraints; k = collision stiffness x mean vertex area). The
        rank-one contact Hessians are lumped onto diagonal blocks (a Gershgorin bound of the
        exact blocks), which keeps the matrix pattern fixed and the system SPD. Returns the
        active contacts with their normal forces, for friction."""
        cs = self.model.collision
        h = cs.thickness
        pts = _contact_points(c, x, ob1)
        gap = np.einsum("ck,ckd,cd->c", c.w, pts.pos, c.n)
        depth = np.maximum(h - gap, 0.0)
        active = depth > 0
        if not active.any():
            return None
        act = _select(c, pts, active)
        depth = depth[active]
        k = cs.stiffness * float(self.model.vertex_area.mean())
        fn = k * depth**2 / (2 * h)
        stiff = k * depth / h
        wc = np.where(act.is_cloth, act.w, 0.0)
        lump = np.abs(wc) * np.abs(wc).sum(1, keepdims=True)
        nn = act.n[:, :, None] * act.n[:, None, :]
        verts = act.cloth_i[act.is_cloth]
        force = ((fn[:, None] * wc)[..., None] * act.n[:, None, :])[act.is_cloth]
        f += _scatter_rows(force, verts, len(f))
        blocks = (stiff[:, None] * lump)[..., None, None] * nn[:, None]
        add_diagonal_blocks(H, self.pattern.diag_block, verts, np.ascontiguousarray(blocks[act.is_cloth]))
        act.fn = fn
        act.stiff = stiff
        return act

    def _add_friction_terms(self, act, v, ob0, ob1, dt, D, f) -> None:
        """Coulomb friction as a force in the implicit solve, lagged and regularised (as in
        ARCSim's friction and IPC's lagged friction): on each contact with normal force fn
        and relative tangential velocity vt at the start of the step,
            f_k = -w_k c P (sum_l w_l v_l),   c = mu fn / max(|vt|, slip speed),
        P = I - n n^T, with its velocity Jacobian -c w_k w_l P lumped onto the diagonal
        (a Gershgorin bound, like the contact penalty). A sliding contact feels mu fn
        against its motion; a resting one is damped so hard that it creeps at most at the
        slip speed; and the friction force is balanced against the elastic forces inside
        the solve, so it can never hold a stiff fabric against more than mu fn."""
        cs = self.model.collision
        vel_ob = (ob1 - ob0) / dt if len(ob1) else np.zeros((1, 3))
        vel = np.where(act.is_cloth[..., None], v[act.cloth_i], vel_ob[act.ob_i])
        vr = np.einsum("ck,ckd->cd", act.w, vel)
        vt = vr - np.sum(vr * act.n, 1, keepdims=True) * act.n
        mu = np.where(act.is_cloth.all(1), cs.self_friction, cs.friction)
        c = mu * act.fn / np.maximum(np.linalg.norm(vt, axis=1), FRICTION_SLIP_SPEED)
        keep = c > 0
        if not keep.any():
            return
        wc = np.where(act.is_cloth, act.w, 0.0)[keep]
        sel = act.is_cloth[keep]
        verts = act.cloth_i[keep][sel]
        force = -(c[keep, None] * wc)[..., None] * vt[keep][:, None, :]  # [C,4,3]
        f += _scatter_rows(force[sel], verts, len(f))
        lump = c[keep, None] * np.abs(wc) * np.abs(wc).sum(1, keepdims=True)
        n = act.n[keep]
        tangent = np.eye(3)[None] - n[:, :, None] * n[:, None, :]
        blocks = lump[..., None, None] * tangent[:, None]
        add_diagonal_blocks(D, self.pattern.diag_block, verts, np.ascontiguousarray(blocks[sel]))

    def collision_response(self, x0: np.ndarray, x1: np.ndarray, ob0: np.ndarray, ob1: np.ndarray):
        """`resolve_collisions` of the move x0 -> x1 (obstacles ob0 -> ob1) with this model's
        masses, topology, pins and thickness: (positions, report)."""
        m = self.model
        return col.resolve_collisions(
            x0, x1, self.mass, self._faces_np, self._edges_np, ob0, ob1, m.obstacles.faces, m.obstacles.edges,
            m.collision.thickness, pinned_mask=self.pinned_mask, self_collision=m.collision.self_collision,
        )

    def _respond(self, x0, x1, ob0, ob1, stats: StepStats, allow_fallback: bool):
        m = self.model
        x_fixed, report = self.collision_response(x0, x1, ob0, ob1)
        self.last_collision = report
        stats.impacts = report.impacts_found
        stats.collision_iterations = report.iterations
        if report.success and np.all(np.isfinite(x_fixed)):
            return x_fixed, True
        if not allow_fallback:
            return x1, False
        stats.fallback = True
        x_safe = col.rigid_impact_zone_fallback(
            x0, x_fixed if np.all(np.isfinite(x_fixed)) else x1, self.mass, self._faces_np, self._edges_np,
            ob0, ob1, m.obstacles.faces, m.obstacles.edges, m.collision.thickness,
            pinned_mask=self.pinned_mask, self_collision=m.collision.self_collision,
        )
        return x_safe, True


@dataclass
class _ContactPoints:
    """The four points of every contact resolved to cloth or obstacle vertices."""

    idx: np.ndarray
    w: np.ndarray
    n: np.ndarray
    is_cloth: np.ndarray
    cloth_i: np.ndarray
    ob_i: np.ndarray
    pos: np.ndarray
    fn: np.ndarray | None = None
    stiff: np.ndarray | None = None


def _contact_points(c, x: np.ndarray, ob: np.ndarray) -> _ContactPoints:
    is_cloth = c.idx >= 0
    cloth_i = np.where(is_cloth, c.idx, 0)
    ob_i = np.where(is_cloth, 0, -c.idx - 1)
    ob_pos = ob[ob_i] if len(ob) else np.zeros(cloth_i.shape + (3,))
    pos = np.where(is_cloth[..., None], x[cloth_i], ob_pos)
    return _ContactPoints(c.idx, c.w, c.n, is_cloth, cloth_i, ob_i, pos)


def _select(c, pts: _ContactPoints, mask: np.ndarray) -> _ContactPoints:
    return _ContactPoints(c.idx[mask], c.w[mask], c.n[mask], pts.is_cloth[mask], pts.cloth_i[mask], pts.ob_i[mask], pts.pos[mask])


def _scatter_rows(values: np.ndarray, rows: np.ndarray, n: int) -> np.ndarray:
    """out[rows[i]] += values[i] for [M,3] values (bincount: much faster than np.add.at)."""
    out = np.empty((n, 3))
    for d in range(3):
        out[:, d] = np.bincount(rows, weights=values[:, d], minlength=n)
    return out


def _scatter_vertex_grad(grad: np.ndarray, elements: np.ndarray, n: int) -> np.ndarray:
    """Sum per-element gradients [E, 3k] onto vertices -> [n,3]."""
    k = elements.shape[1]
    out = np.zeros((n, 3))
    g = grad.reshape(len(elements), k, 3)
    for d in range(3):
        out[:, d] = np.bincount(elements.ravel(), weights=g[:, :, d].ravel(), minlength=n)
    return out
