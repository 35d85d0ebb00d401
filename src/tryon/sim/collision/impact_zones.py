"""Collision response: impact zones with an exact inelastic projection (Harmon et al. 2008;
ARCSim's collision.cpp, Narain et al. 2012), and Bridson et al.'s (2002) rigid impact
zones as the last-resort fail-safe.

Each iteration finds the impacts on the linear path from the (intersection-free) start
positions x0 to the current end positions, adds one linearised constraint per impact

    g_c(z) = sum_k w_ck n_c . z_k >= target          (target = gap_fraction * thickness)

(obstacle points at their end positions and pinned vertices fixed), and projects the
candidate positions x1 onto all constraints found so far in the mass metric:

    min_z 1/2 (z - x1)^T M (z - x1)   s.t.   g_c(z) >= target  for all c.

The projection is solved exactly (`qp.solve_projection`: dual Gauss-Seidel, then an
interior point method when that is slow) to a worst violation below `tol` metres. Impact
zones - groups of vertices coupled through constraints - are solved together in one QP,
whose blocks are independent.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

from tryon.errors import MeshError
from tryon.sim.collision.ccd import find_impacts
from tryon.sim.collision.contacts import Contacts
from tryon.sim.geometry.inputs import as_points, prepare_inputs
from tryon.sim.collision.qp import solve_projection
from tryon.sim.collision.scene import CollisionScene

GAP_FRACTION = 0.1  # ARCSim: projection thickness 1e-4 m vs repulsion thickness 1e-3 m
QP_TOL = 1e-10  # metres of constraint violation


@dataclass
class CollisionReport:
    """Outcome of `resolve_collisions`. `constraints` (with `multipliers`, the dual
    variables) are the linearised impact constraints of the final projection, for the
    differentiable layer; `target_gap` is their right-hand side."""

    iterations: int = 0
    impacts_found: int = 0
    zones: int = 0
    success: bool = True
    max_violation: float = 0.0
    qp_sweeps: int = 0
    ipm_iterations: int = 0
    target_gap: float = 0.0
    constraints: Contacts = field(default_factory=Contacts.empty)
    multipliers: np.ndarray = field(default_factory=lambda: np.zeros(0))
    fallback: bool = False  # the step's response ended with the rigid fail-safe (`ImplicitEulerSolver.respond`)


def count_zones(constraints: Contacts, n_vertices: int) -> int:
    """Number of impact zones: connected groups of cloth vertices coupled by constraints."""
    if len(constraints) == 0:
        return 0
    graph, involved = _coupling_graph(constraints.idx, n_vertices, None, 0)
    _, labels = connected_components(graph, directed=False)
    return int(len(np.unique(labels[involved])))


def _coupling_graph(idx: np.ndarray, n_vertices: int, ob_component: np.ndarray | None, n_ob_components: int):
    """Graph over the cloth vertices plus one node per obstacle component (numbered after
    the cloth; obstacle points are left out when ob_component is None) that links the
    points of each contact. Returns (graph, involved-node mask)."""
    if ob_component is None or len(ob_component) == 0:
        node = np.where(idx >= 0, idx, -1)
    else:
        node = np.where(idx >= 0, idx, n_vertices + ob_component[np.where(idx < 0, -idx - 1, 0)])
    size = n_vertices + n_ob_components
    # chain the points of each contact: every valid point to the next valid one
    order = np.argsort(node < 0, axis=1, kind="stable")  # valid points first
    chain = np.take_along_axis(node, order, axis=1)
    r = np.concatenate([chain[:, k] for k in range(3)])
    c = np.concatenate([chain[:, k + 1] for k in range(3)])
    ok = (r >= 0) & (c >= 0)
    graph = sp.coo_matrix((np.ones(int(ok.sum())), (r[ok], c[ok])), shape=(size, size)).tocsr()
    involved = np.zeros(size, bool)
    involved[node[node >= 0]] = True
    return graph, involved


def _prepare_response(scene: CollisionScene, x0, x1, ob0, ob1):
    masses, pinned_mask = scene.masses, scene.pinned
    ob0 = np.zeros((0, 3)) if ob0 is None else ob0
    x0, faces, edges, ob0, ob_faces, ob_edges = prepare_inputs(x0, scene.faces, scene.edges, ob0, scene.ob_faces,
                                                                scene.ob_edges)
    x1 = as_points(x1, "cloth end positions")
    ob1 = as_points(ob1 if ob1 is not None else np.zeros((0, 3)), "obstacle end positions")
    if x1.shape != x0.shape or ob1.shape != ob0.shape:
        raise MeshError(f"start/end positions differ in shape: cloth {x0.shape} vs {x1.shape}, obstacle {ob0.shape} vs {ob1.shape}")
    masses = np.ascontiguousarray(np.asarray(masses.detach().numpy() if hasattr(masses, "detach") else masses, np.float64))
    if masses.shape != (len(x0),) or not np.all(masses > 0):
        raise MeshError(f"masses: expected {len(x0)} positive vertex masses, got shape {list(masses.shape)}")
    pinned = np.zeros(len(x0), bool) if pinned_mask is None else np.asarray(pinned_mask, bool).reshape(-1)
    if hasattr(pinned_mask, "detach"):
        pinned = pinned_mask.detach().numpy().astype(bool).reshape(-1)
    if pinned.shape != (len(x0),):
        raise MeshError(f"pinned_mask: expected {len(x0)} booleans, got shape {list(pinned.shape)}")
    return x0, x1, masses, faces, edges, ob0, ob1, ob_faces, ob_edges, pinned


def resolve_collisions(
    scene: CollisionScene,
    x0: Any,
    x1: Any,
    ob0: Any = None,
    ob1: Any = None,
    max_iterations: int = 30,
    gap_fraction: float = GAP_FRACTION,
    tol: float = QP_TOL,
    trace: list | None = None,
    max_impacts: int | None = None,
) -> tuple[np.ndarray, CollisionReport]:
    """Impact-zone collision response (see the module docstring). x0 must be free of
    intersections; on success the returned positions are, and no impact remains between x0
    and them. Pinned vertices and obstacles are not moved. Returns (positions, report).
    `trace`, when a list, receives one tuple (positions the impacts were found against,
    number of new constraints appended, QPResult) per projection, for `tryon.diff`.
    More than `max_impacts` impacts at once (default: twice the vertex count, at least
    2000) means the candidate positions are not a collision problem but a failed step:
    the response gives up at once rather than projecting a whole garment."""
    x0, x1, masses, faces, edges, ob0, ob1, ob_faces, ob_edges, pinned = _prepare_response(scene, x0, x1, ob0, ob1)
    thickness, self_collision = scene.thickness, scene.self_collision
    target = float(gap_fraction * thickness)
    report = CollisionReport(target_gap=target)
    if not np.all(np.isfinite(x1)):
        report.success = False
        report.max_violation = float("inf")
        return x1.copy(), report
    inv_mass = np.where(pinned, 0.0, 1.0 / masses)
    constraints = Contacts.empty()
    lam = np.zeros(0)
    x = x1.copy()
    report.success = False
    limit = max(2000, 2 * len(x0)) if max_impacts is None else max_impacts
    for it in range(max_iterations + 1):
        impacts = find_impacts(x0, x, faces, edges, ob0, ob1, ob_faces, ob_edges, thickness, self_collision, alias=scene.alias, trees=scene.trees)
        if len(impacts) == 0:
            report.success = True
            break
        if it == max_iterations or len(constraints) + len(impacts) > limit:
            break
        report.impacts_found += len(impacts)
        constraints = constraints + impacts
        lam = np.concatenate([lam, np.zeros(len(impacts))])
        qp = solve_projection(x1, inv_mass, constraints.idx, constraints.w, constraints.n, ob1, target, lam, tol)
        if trace is not None:
            trace.append((x, len(impacts), qp))
        x, lam = qp.z, qp.lam
        report.iterations = it + 1
        report.qp_sweeps += qp.sweeps
        report.ipm_iterations += qp.ipm_iterations
        report.max_violation = qp.violation
    if report.success and report.iterations and not _plausible_projection(x0, x1, x, masses, ob0, ob1, thickness):
        report.success = False  # an infeasible or unconverged projection flung vertices away
    report.zones = count_zones(constraints, len(x0))
    report.constraints = constraints
    report.multipliers = lam
    return x, report


def _plausible_projection(x0, x1, z, masses, ob0, ob1, thickness) -> bool:
    """The start positions, carried along by the obstacles' largest displacement, are (up
    to the target gap) feasible, so the exact projection of x1 lies no farther from x1, in
    the mass norm, than that; a result far beyond it comes from contradictory constraints
    (an infeasible or unconverged projection), not from the geometry."""
    def mass_norm(d):
        return float(np.sqrt(np.sum(masses[:, None] * d * d)))

    carried = float(np.linalg.norm(ob1 - ob0, axis=1).max()) if len(ob0) else 0.0
    bound = 2.0 * (mass_norm(x1 - x0) + np.sqrt(masses.sum()) * (carried + thickness))
    return mass_norm(z - x1) <= bound


# --------------------------------------------------------------------------- rigid fail-safe
def obstacle_components(n_ob: int, ob_faces: np.ndarray) -> tuple[int, np.ndarray]:
    """Connected components of the obstacle soup (one per merged obstacle, normally)."""
    if n_ob == 0:
        return 0, np.zeros(0, np.int64)
    f = ob_faces
    r = np.concatenate([f[:, 0], f[:, 1], f[:, 2]])
    c = np.concatenate([f[:, 1], f[:, 2], f[:, 0]])
    g = sp.coo_matrix((np.ones(len(r)), (r, c)), shape=(n_ob, n_ob)).tocsr()
    k, labels = connected_components(g, directed=False)
    return int(k), labels.astype(np.int64)


def _rotation_from_vector(theta: np.ndarray) -> np.ndarray:
    """Rodrigues' formula for rotation vectors [Z,3] -> matrices [Z,3,3]."""
    angle = np.linalg.norm(theta, axis=1)
    axis = np.divide(theta, angle[:, None], out=np.zeros_like(theta), where=angle[:, None] > 0)
    kx = np.zeros((len(theta), 3, 3))
    kx[:, 0, 1], kx[:, 0, 2] = -axis[:, 2], axis[:, 1]
    kx[:, 1, 0], kx[:, 1, 2] = axis[:, 2], -axis[:, 0]
    kx[:, 2, 0], kx[:, 2, 1] = -axis[:, 1], axis[:, 0]
    s = np.sin(angle)[:, None, None]
    c = np.cos(angle)[:, None, None]
    return np.eye(3)[None] + s * kx + (1 - c) * kx @ kx


def _zone_sum(zone: np.ndarray, values: np.ndarray, n_zones: int) -> np.ndarray:
    out = np.zeros((n_zones,) + values.shape[1:])
    np.add.at(out, zone, values)
    return out


def _momentum_motions(x0, x1, masses, zone, n_zones):
    """Rigid motion of each free zone preserving its linear and angular momentum
    (Bridson et al. 2002, sec. 7.4): returns (R [Z,3,3], c0 [Z,3], c1 [Z,3])."""
    m = masses[:, None]
    mz = _zone_sum(zone, masses, n_zones)[:, None]
    c0 = _zone_sum(zone, m * x0, n_zones) / mz
    c1 = _zone_sum(zone, m * x1, n_zones) / mz
    r = x0 - c0[zone]
    u = (x1 - x0) - (c1 - c0)[zone]
    ang = _zone_sum(zone, m * np.cross(r, u), n_zones)
    rr = np.einsum("ij,ik->ijk", r, r)
    inertia = _zone_sum(zone, masses[:, None, None] * (np.sum(r * r, 1)[:, None, None] * np.eye(3) - rr), n_zones)
    theta = np.einsum("zij,zj->zi", np.linalg.pinv(inertia, rcond=1e-10, hermitian=True), ang)
    angle = np.linalg.norm(theta, axis=1, keepdims=True)
    theta = np.where(angle > 0.5 * np.pi, theta * (0.5 * np.pi) / np.maximum(angle, 1e-300), theta)
    return _rotation_from_vector(theta), c0, c1


def _kinematic_motions(p0, p1, zone, n_zones):
    """Best-fit rigid motion (Kabsch 1976) of each zone's kinematic points p0 -> p1."""
    cnt = np.bincount(zone, minlength=n_zones).astype(float)[:, None]
    c0 = _zone_sum(zone, p0, n_zones) / np.maximum(cnt, 1)
    c1 = _zone_sum(zone, p1, n_zones) / np.maximum(cnt, 1)
    h = _zone_sum(zone, np.einsum("ij,ik->ijk", p0 - c0[zone], p1 - c1[zone]), n_zones)
    u, _, vt = np.linalg.svd(h)
    d = np.sign(np.linalg.det(np.einsum("zji,zkj->zik", vt, u)))
    d[d == 0] = 1.0
    fix = np.ones((n_zones, 3))
    fix[:, 2] = d
    rot = np.einsum("zji,zj,zkj->zik", vt, fix, u)
    return rot, c0, c1


def _rigid_zone_positions(x0, x1, masses, pinned, labels, involved, ob0, ob1, ob_comp, n_vertices):
    """Move every zone of involved vertices rigidly: with its kinematic partners (pinned
    vertices, touched obstacle components) when it has any, else with its own momentum."""
    x = x1.copy()
    verts = np.flatnonzero(involved[:n_vertices])
    if len(verts) == 0:
        return x
    zone_labels, zone = np.unique(labels[verts], return_inverse=True)
    n_zones = len(zone_labels)
    kin_zone, kin0, kin1 = [], [], []
    pin_v = verts[pinned[verts]]
    if len(pin_v):
        kin_zone.append(zone[pinned[verts]])
        kin0.append(x0[pin_v])
        kin1.append(x1[pin_v])
    if len(ob_comp):
        comp_label = labels[n_vertices + ob_comp]  # zone label of each obstacle vertex's component
        sel = np.isin(comp_label, zone_labels)
        if sel.any():
            kin_zone.append(np.searchsorted(zone_labels, comp_label[sel]))
            kin0.append(ob0[sel])
            kin1.append(ob1[sel])
    rot, c0, c1 = _momentum_motions(x0[verts], x1[verts], masses[verts], zone, n_zones)
    if kin_zone:
        kz = np.concatenate(kin_zone)
        krot, kc0, kc1 = _kinematic_motions(np.concatenate(kin0), np.concatenate(kin1), kz, n_zones)
        has_kin = np.bincount(kz, minlength=n_zones) > 0
        rot[has_kin], c0[has_kin], c1[has_kin] = krot[has_kin], kc0[has_kin], kc1[has_kin]
    x[verts] = np.einsum("zij,zj->zi", rot[zone], x0[verts] - c0[zone]) + c1[zone]
    x[pinned] = x1[pinned]
    return x


def rigid_impact_zone_fallback(scene: CollisionScene, x0: Any, x1: Any, ob0: Any = None, ob1: Any = None,
                               max_iterations: int = 100) -> np.ndarray:
    """Rigid impact zones (Bridson, Fedkiw & Anderson 2002, sec. 7.4), the fail-safe.

    Vertices of colliding primitives are merged into zones; a zone that touches an
    obstacle or contains pinned vertices moves with the best-fit rigid motion of those
    (the obstacle's own motion when it is rigid), any other zone with the rigid motion
    that keeps its linear and angular momentum. Rigid motions, interpolated linearly, are
    invertible affine maps, so a zone never intersects itself or the obstacle it rides
    with; zones keep merging until no impact is left. If x0 is intersection-free and
    every zone's kinematic partners move rigidly together, so is the result."""
    x0, x1, masses, faces, edges, ob0, ob1, ob_faces, ob_edges, pinned = _prepare_response(scene, x0, x1, ob0, ob1)
    thickness, self_collision = scene.thickness, scene.self_collision
    n = len(x0)
    x1 = np.where(np.isfinite(x1), x1, x0)
    n_comp, ob_comp = obstacle_components(len(ob0), ob_faces)
    size = n + n_comp
    links = sp.csr_matrix((size, size))
    involved = np.zeros(size, bool)
    x = x1.copy()
    prev = None
    for _ in range(max_iterations):
        impacts = find_impacts(x0, x, faces, edges, ob0, ob1, ob_faces, ob_edges, thickness, self_collision, alias=scene.alias, trees=scene.trees)
        if len(impacts) == 0:
            return x
        graph, inv = _coupling_graph(impacts.idx, n, ob_comp, n_comp)
        links = links + graph
        involved |= inv
        _, labels = connected_components(links, directed=False)
        key = (involved.sum(), len(np.unique(labels[involved])))
        if key == prev:
            break  # no zone grew: go to the last resort
        prev = key
        x = _rigid_zone_positions(x0, x1, masses, pinned, labels, involved, ob0, ob1, ob_comp, n)
    # last resort: the whole cloth as one zone riding with everything kinematic
    involved[:] = True
    x_all = _rigid_zone_positions(x0, x1, masses, pinned, np.zeros(size, np.int64), involved, ob0, ob1, ob_comp, n)
    left = len(find_impacts(x0, x_all, faces, edges, ob0, ob1, ob_faces, ob_edges, thickness, self_collision, alias=scene.alias, trees=scene.trees))
    if left == 0:
        return x_all
    frozen = x0.copy()
    frozen[pinned] = x1[pinned]
    left_frozen = len(find_impacts(x0, frozen, faces, edges, ob0, ob1, ob_faces, ob_edges, thickness, self_collision, alias=scene.alias, trees=scene.trees))
    return frozen if left_frozen < left else x_all
