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

The step is composed of four public phases, which `tryon.diff` composes the same way to
record a differentiable step: `detect_contacts` (proximity at the start of the step),
`assemble` (forces, contact and friction potentials, the matrix: a `StepSystem`),
`solve` (the linear solve for dv) and `respond` (CCD and impact zones).
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass, field

import numpy as np
import torch

from tryon.errors import SimulationError
from tryon.fabric.base import Fabric
from tryon.sim import collision as col
from tryon.sim.collision.contacts import Contacts
from tryon.sim.collision.scene import CollisionScene
from tryon.sim.forces.bending import bending_forces_rank_one
from tryon.sim.forces.contact import (
    FRICTION_SLIP_SPEED,
    friction_coefficient,
    lumped_weights,
    penalty_force,
    penalty_stiffness,
)
from tryon.sim.forces.membrane import membrane_forces
from tryon.sim.forces.wind import wind_forces
from tryon.sim.linear import (BlockPattern, LinearSolver, add_diagonal_blocks, bsr_matvec, scatter_element_blocks,
                              scatter_rank_one_blocks)
from tryon.sim.model import ClothModel, ClothState, Control

__all__ = ["ActiveContacts", "FRICTION_SLIP_SPEED", "ImplicitEulerSolver", "StepOptions", "StepStats", "StepSystem"]


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
        self._membrane_hessians = torch.empty((len(faces), 9, 9), dtype=torch.float64)  # reused: no page faults
        self._last_dv: np.ndarray | None = None
        self.collisions = CollisionScene.of(faces, model.edges, self.mass, model.obstacles.faces, model.obstacles.edges,
                                            model.collision.thickness, self.pinned_mask, model.collision.self_collision,
                                            stitches=self._stitches)
        self.last_collision: col.CollisionReport | None = None  # the latest response's report, for diagnoses

    # ------------------------------------------------------------------ public API
    def step(self, state: ClothState, dt: float, control: Control | None = None) -> tuple[ClothState, StepStats]:
        """One time step of length dt; retried with substeps when it fails."""
        if dt <= 0:
            raise SimulationError(f"time step must be positive, got dt={dt}")
        stats = StepStats()
        out = self._advance_with_retries(state, dt, control, 0, stats)
        return out, stats

    def use_fabric(self, fabric: Fabric) -> None:
        """Use `fabric` (its detached values) from the next step on: stiffness and masses.
        The one named way to change the material during a run (fabric estimation does)."""
        self.fabric = fabric
        self.mass = self.model.mass(fabric).detach().numpy().astype(np.float64)
        self._mass_blocks = self.mass[:, None, None] * np.eye(3)[None]
        self.collisions = dataclasses.replace(self.collisions, masses=self.mass)

    def checkpoint_arrays(self) -> dict[str, np.ndarray]:
        """What, besides the cloth state, decides the next step's result: the linear
        solver's warm start and the cached BVH topologies of the collision queries.
        Saved with a checkpoint, restored by `restore_arrays`, a resumed run repeats the
        uninterrupted one bit for bit."""
        arrays = self.collisions.trees.export()
        if self._last_dv is not None:
            arrays["solver_last_dv"] = self._last_dv
        return arrays

    def restore_arrays(self, arrays: dict[str, np.ndarray]) -> None:
        """Undo-free counterpart of `checkpoint_arrays` (call before the first step)."""
        last = arrays.get("solver_last_dv")
        if last is not None and (np.shape(last) != (self.model.num_vertices, 3) or not np.all(np.isfinite(last))):
            raise ValueError("the solver's warm start does not fit the cloth")
        self.collisions.trees.load(arrays)
        self._last_dv = None if last is None else np.array(last, dtype=np.float64)

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
        ob0 = m.obstacles.vertices_at(state.t)
        ob1 = m.obstacles.vertices_at(state.t + dt)

        tic = time.perf_counter()
        contacts = self.detect_contacts(x, ob1)
        stats.contacts = 0 if contacts is None else len(contacts)
        system = self.assemble(state, dt, control, contacts, ob0, ob1)
        stats.seconds["forces"] = time.perf_counter() - tic

        tic = time.perf_counter()
        dv = self.solve(system, guess=self._last_dv)
        stats.solver_iterations = self.linear.last_iterations
        stats.seconds["solve"] = time.perf_counter() - tic
        if not np.all(np.isfinite(dv)):
            return state, False, stats
        x_new, v_new = self.candidate(system, dv, dt)
        speed = np.linalg.norm(v_new, axis=1)
        if speed.max() > self.options.max_speed:
            if not allow_fallback:
                return state, False, stats
            # last resort: cap the runaway velocities so the fail-safe gets a sane candidate
            stats.fallback = True
            v_new *= np.minimum(1.0, self.options.max_speed / np.maximum(speed, 1e-300))[:, None]
            x_new = x + dt * v_new
            x_new[self.pinned_mask] = system.targets

        tic = time.perf_counter()
        ok = True
        if self.options.collisions and m.collision.enabled:
            x_new, ok, report = self.respond(x, x_new, ob0, ob1, allow_fallback)
            stats.impacts, stats.collision_iterations = report.impacts_found, report.iterations
            stats.fallback |= report.fallback
        stats.seconds["collision"] = time.perf_counter() - tic
        if not ok:
            return state, False, stats
        self._last_dv = dv
        v_new = (x_new - x) / dt
        return ClothState(torch.from_numpy(x_new), torch.from_numpy(v_new), state.t + dt), True, stats

    # ------------------------------------------------------------------ phases of a step
    def detect_contacts(self, x: np.ndarray, ob1: np.ndarray) -> Contacts | None:
        """Proximity contacts (cloth-cloth and cloth-obstacle within the thickness) at the
        start of the step, against the obstacles' end-of-step positions; None when
        collisions are off."""
        if not (self.options.collisions and self.model.collision.enabled):
            return None
        return self.collisions.proximities(x, ob1)

    def assemble(self, state: ClothState, dt: float, control: Control | None, contacts: Contacts | None,
                 ob0: np.ndarray, ob1: np.ndarray) -> "StepSystem":
        """Forces, stiffness and damping of every term at the start of the step (elastic,
        wind, air, stitches, the contact penalty and friction potentials) and the implicit
        system (M + dt D + dt^2 H) dv = dt (f - dt H v) with the pinned vertices' dv."""
        x = state.x.detach().numpy()
        v = state.v.detach().numpy()
        H, D, f = self._elastic_and_air(state, control)
        self._add_soft_handles(x, state.t + dt, f, H)
        active = None
        if contacts is not None and len(contacts):
            friction = None if control is None else control.friction
            active = self._add_contact_terms(contacts, x, v, ob1, H, f, friction)
            if active is not None:
                self._add_friction_terms(active, v, ob0, ob1, dt, D, f)
        A = dt * dt * H + dt * D
        A[self.pattern.diag_block] += self._mass_blocks
        Hv = np.zeros_like(v)
        bsr_matvec(self.pattern.indptr, self.pattern.indices, H, v, Hv)
        targets = self.model.pin_targets(state.t + dt).numpy()
        fixed_dv = (targets - x[self.pinned_mask]) / dt - v[self.pinned_mask]
        return StepSystem(x=x, v=v, H=H, D=D, f=f, A=A, rhs=dt * (f - dt * Hv), targets=targets, fixed_dv=fixed_dv,
                          contacts=active)

    def solve(self, system: "StepSystem", guess: np.ndarray | None = None) -> np.ndarray:
        """dv [N,3] of the assembled system with this solver's linear solver (PCG warm
        started from `guess`, or a direct factorisation)."""
        return self.linear.solve(system.A, system.rhs, self.pinned_mask, system.fixed_dv, guess=guess)

    def candidate(self, system: "StepSystem", dv: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
        """Candidate end-of-step positions and velocities for dv (pinned vertices on their targets)."""
        v_new = system.v + dv
        x_new = system.x + dt * v_new
        x_new[self.pinned_mask] = system.targets
        return x_new, v_new

    def respond(self, x0: np.ndarray, x1: np.ndarray, ob0: np.ndarray, ob1: np.ndarray, allow_fallback: bool,
                trace: list | None = None) -> tuple[np.ndarray, bool, "col.CollisionReport"]:
        """Intersection-free positions for the move x0 -> x1 (CCD and impact zones; with
        `allow_fallback`, rigid impact zones when those fail): (positions, ok, report).
        `trace`, when given, records the impact-zone projections (for `tryon.diff`)."""
        x_fixed, report = self.collision_response(x0, x1, ob0, ob1, trace=trace)
        self.last_collision = report
        if report.success and np.all(np.isfinite(x_fixed)):
            return x_fixed, True, report
        if not allow_fallback:
            return x1, False, report
        report.fallback = True
        if trace is not None:
            trace.clear()
        x_safe = col.rigid_impact_zone_fallback(self.collisions, x0, x_fixed if np.all(np.isfinite(x_fixed)) else x1,
                                                ob0, ob1)
        return x_safe, True, report

    # ------------------------------------------------------------------ terms
    def _elastic_and_air(self, state: ClothState, control: Control | None):
        """Stiffness blocks H, damping blocks D and total force f [N,3] (numpy)."""
        m, fab = self.model, self.fabric
        x, v = state.x, state.v
        H = self.pattern.zeros()
        D = self.pattern.zeros()
        with torch.no_grad():
            _, g_mem, h_mem = membrane_forces(x, m.faces, m.Dm_inv, m.rest_area, m.stretching_law(fab.stretching_stiffness),
                                              hess_out=self._membrane_hessians)
            _, g_bend, c_bend, dtheta = bending_forces_rank_one(
                x, m.hinges, m.hinge_rest_theta, m.hinge_area_sum, m.hinge_edge_dir_uv, m.bending_law(fab.bending_stiffness)
            )
            wind_v = m.wind.velocity if control is None or control.wind_velocity is None else control.wind_velocity
            f_wind, d_wind = wind_forces(
                x, v, m.faces, m.rest_area, torch.as_tensor(wind_v, dtype=x.dtype), m.wind.density, m.wind.drag,
                with_jacobian=m.wind.implicit,
            )
        n = m.num_vertices
        f = -_scatter_vertex_grad(g_mem.numpy(), self.collisions.faces, n) - _scatter_vertex_grad(g_bend, m.hinges.numpy(), n)
        f += f_wind.numpy()
        f += self.mass[:, None] * m.gravity.numpy()[None]
        if control is not None and control.external_force is not None:
            f += control.external_force.detach().numpy()
        scatter_element_blocks(H, self.pattern.element_maps[0], np.ascontiguousarray(h_mem.numpy()), 3)
        scatter_rank_one_blocks(H, self.pattern.element_maps[1], c_bend, dtheta, 4)
        if d_wind is not None:
            scatter_element_blocks(D, self.pattern.element_maps[0], np.ascontiguousarray(d_wind.numpy()), 3)
        stitch_k = m.stitch_stiffness if control is None or control.stitch_stiffness is None else control.stitch_stiffness
        if len(self._stitches) and stitch_k > 0:
            self._add_stitches(x.numpy(), f, H, stitch_k)
        if m.damping > 0:
            D += m.damping * H
        air = m.air_damping if control is None or control.air_damping is None else control.air_damping
        if air > 0:
            D[self.pattern.diag_block] += air * self._mass_blocks
            f -= air * self.mass[:, None] * v.numpy()
        return H, D, f

    def _add_soft_handles(self, x: np.ndarray, t_end: float, f: np.ndarray, H: np.ndarray) -> None:
        """Springs E = k/2 |x - target(t_end)|^2 of the soft handles (ARCSim's node handles:
        the target is the handle's position at the end of the step)."""
        idx, k, target = self.model.handle_springs(t_end)
        if len(idx) == 0:
            return
        np.add.at(f, idx, -k[:, None] * (x[idx] - target))
        np.add.at(H, self.pattern.diag_block[idx], k[:, None, None] * np.eye(3)[None])

    def _add_stitches(self, x: np.ndarray, f: np.ndarray, H: np.ndarray, k: float) -> None:
        """Zero-length springs E = k/2 |x_i - x_j|^2 between stitched vertices (sewing)."""
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
        ob = self.model.obstacles.vertices_at(t)
        f = np.zeros_like(x)
        if len(ob) == 0:
            return f
        c = self.collisions.proximities(x, ob, self_collision=False)
        if len(c):
            self._add_contact_terms(c, x, np.zeros_like(x), ob, self.pattern.zeros(), f)
        return f

    def contact_stiffness(self) -> float:
        """k of the penalty: the collision stiffness times the mean vertex area."""
        return self.model.collision.stiffness * float(self.model.vertex_area.mean())

    def _add_contact_terms(self, c: Contacts, x, v, ob1, H, f, friction: float | None = None) -> "ActiveContacts | None":
        """The penalty potential (`tryon.sim.forces.contact`) of every contact whose gap is
        below the thickness, into f and (lumped) H. Returns those active contacts with
        their normal forces, for friction."""
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
        k = self.contact_stiffness()
        fn = penalty_force(depth, h, k)
        stiff = penalty_stiffness(depth, h, k)
        wc = np.where(act.is_cloth, act.w, 0.0)
        lump = lumped_weights(wc)
        nn = act.n[:, :, None] * act.n[:, None, :]
        verts = act.cloth_i[act.is_cloth]
        force = ((fn[:, None] * wc)[..., None] * act.n[:, None, :])[act.is_cloth]
        f += _scatter_rows(force, verts, len(f))
        blocks = (stiff[:, None] * lump)[..., None, None] * nn[:, None]
        add_diagonal_blocks(H, self.pattern.diag_block, verts, np.ascontiguousarray(blocks[act.is_cloth]))
        act.fn = fn
        act.stiff = stiff
        act.mu = np.where(act.is_cloth.all(1), cs.self_friction, cs.friction if friction is None else friction)
        return act

    def _add_friction_terms(self, act: "ActiveContacts", v, ob0, ob1, dt, D, f) -> None:
        """The lagged friction potential (`tryon.sim.forces.contact`) of the active contacts,
        into f and (lumped) D: balanced against the elastic forces inside the solve, so it
        can never hold a stiff fabric against more than mu fn."""
        vel_ob = (ob1 - ob0) / dt if len(ob1) else np.zeros((1, 3))
        vel = np.where(act.is_cloth[..., None], v[act.cloth_i], vel_ob[act.ob_i])
        vr = np.einsum("ck,ckd->cd", act.w, vel)
        vt = vr - np.sum(vr * act.n, 1, keepdims=True) * act.n
        c = friction_coefficient(act.mu, act.fn, np.maximum(np.linalg.norm(vt, axis=1), FRICTION_SLIP_SPEED))
        keep = c > 0
        if not keep.any():
            return
        wc = np.where(act.is_cloth, act.w, 0.0)[keep]
        sel = act.is_cloth[keep]
        verts = act.cloth_i[keep][sel]
        force = -(c[keep, None] * wc)[..., None] * vt[keep][:, None, :]  # [C,4,3]
        f += _scatter_rows(force[sel], verts, len(f))
        lump = lumped_weights(wc, scale=c[keep, None])
        n = act.n[keep]
        tangent = np.eye(3)[None] - n[:, :, None] * n[:, None, :]
        blocks = lump[..., None, None] * tangent[:, None]
        add_diagonal_blocks(D, self.pattern.diag_block, verts, np.ascontiguousarray(blocks[sel]))

    def collision_response(self, x0: np.ndarray, x1: np.ndarray, ob0: np.ndarray, ob1: np.ndarray,
                           trace: list | None = None):
        """`resolve_collisions` of the move x0 -> x1 (obstacles ob0 -> ob1) with this model's
        masses, topology, pins and thickness: (positions, report)."""
        return col.resolve_collisions(self.collisions, x0, x1, ob0, ob1, trace=trace)


@dataclass
class StepSystem:
    """The implicit system of one step, assembled at its start (`ImplicitEulerSolver.assemble`)."""

    x: np.ndarray  # [N,3] positions at the start
    v: np.ndarray  # [N,3] velocities at the start
    H: np.ndarray  # stiffness blocks (elastic, stitches, contact penalties)
    D: np.ndarray  # damping blocks (wind, air, Rayleigh, friction)
    f: np.ndarray  # [N,3] forces
    A: np.ndarray  # blocks of M + dt D + dt^2 H
    rhs: np.ndarray  # [N,3] dt (f - dt H v)
    targets: np.ndarray  # [P,3] pinned vertices' positions at the end of the step
    fixed_dv: np.ndarray  # [P,3] the pinned vertices' dv
    contacts: "ActiveContacts | None"


@dataclass
class ActiveContacts:
    """The proximity contacts active in a step (gap below the thickness): the contacts
    themselves, their four points resolved to cloth or obstacle vertices, and, once the
    penalty is assembled, their normal forces, penalty stiffness and friction coefficients."""

    contacts: Contacts
    is_cloth: np.ndarray  # [C,4]
    cloth_i: np.ndarray  # [C,4] cloth vertex of each point (0 at obstacle points)
    ob_i: np.ndarray  # [C,4] obstacle vertex of each point (0 at cloth points)
    pos: np.ndarray  # [C,4,3] point positions at the start of the step
    fn: np.ndarray | None = None
    stiff: np.ndarray | None = None
    mu: np.ndarray | None = None

    @property
    def idx(self) -> np.ndarray:
        return self.contacts.idx

    @property
    def w(self) -> np.ndarray:
        return self.contacts.w

    @property
    def n(self) -> np.ndarray:
        return self.contacts.n

    def __len__(self) -> int:
        return len(self.contacts)


def _contact_points(c: Contacts, x: np.ndarray, ob: np.ndarray) -> ActiveContacts:
    is_cloth = c.idx >= 0
    cloth_i = np.where(is_cloth, c.idx, 0)
    ob_i = np.where(is_cloth, 0, -c.idx - 1)
    ob_pos = ob[ob_i] if len(ob) else np.zeros(cloth_i.shape + (3,))
    pos = np.where(is_cloth[..., None], x[cloth_i], ob_pos)
    return ActiveContacts(c, is_cloth, cloth_i, ob_i, pos)


def _select(c: Contacts, pts: ActiveContacts, mask: np.ndarray) -> ActiveContacts:
    return ActiveContacts(c.select(mask), pts.is_cloth[mask], pts.cloth_i[mask], pts.ob_i[mask], pts.pos[mask])


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
