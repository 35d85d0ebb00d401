"""Two-level cloth hierarchy for time-domain parallel simulation (Liang & Lin, SCA 2018, Sec. 3).

The fine level is the cloth whose frames a run returns; the coarse level is the same
cloth at a lower resolution, related by a sparse upsampling operator ``u(X) = U X``
([N_fine, N_coarse], acting on positions and velocities alike). Two ways to build them:

* coarsen (default for grids and garment animations): the scene's own cloth is the fine
  level and the coarse one a coarser triangulation of the same pattern (a grid at a
  lower resolution, or the garment's sewing pattern at a larger edge length, seams
  welded); ``U`` is the barycentric embedding of each fine vertex's material coordinates
  in the coarse triangle of its pattern piece. The output has the serial run's format.
* subdivide (any mesh): the scene's cloth is the coarse level and the fine one its
  midpoint subdivision (1 -> 4 triangles), with the exact linear upsampling.

The mass-weighted left inverse ``R = (U^T M U)^-1 U^T M`` of ``U`` (M the fine lumped
masses) is the restriction that measures the fine mesh's coarse-scale motion; ``R U = I``,
and the mass-weighted closest fine state whose coarse-scale part equals a target ``X`` is
``x + U (X - R x)`` (the TRACKS-style tracking projection used in detail recovery).
"""

from __future__ import annotations

import copy
import dataclasses
import hashlib
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla
import torch
from scipy.spatial import cKDTree

from tryon.errors import SceneError
from tryon.sim.mesh import ClothMesh
from tryon.sim.integrator import ImplicitEulerSolver, StepOptions
from tryon.sim.loop import run
from tryon.sim.geometry import area_vertex_normals
from tryon.sim.model import ClothModel, ClothState, PinGroup, SoftHandle
from tryon.sim.obstacles import Obstacle
from tryon.sim.origin import GridOrigin, PatternMesh, PatternOrigin
from tryon.sim.scene import Scene, parse_scene


# ---------------------------------------------------------------------------- subdivision

def edge_index(faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unique undirected edges [E,2] and, per face, the edge index of its sides
    (v0,v1), (v1,v2), (v2,v0) as [F,3]."""
    sides = np.stack([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]], 1).reshape(-1, 2)
    edges, inverse = np.unique(np.sort(sides, 1), axis=0, return_inverse=True)
    return edges, inverse.reshape(-1, 3)


def subdivide_mesh(mesh: ClothMesh) -> tuple[ClothMesh, sp.csr_matrix]:
    """Midpoint (1 -> 4) subdivision of a cloth mesh and its upsampling operator U.

    Fine vertex i < N is coarse vertex i; fine vertex N + e is the midpoint of coarse edge
    e. Face (a, b, c) with side midpoints (ab, bc, ca) becomes (a, ab, ca), (ab, b, bc),
    (ca, bc, c), (ab, bc, ca), which keeps the orientation. Vertex and per-corner material
    coordinates of the midpoints are the means of their edge's ends, so the fine rest shape
    is exactly the coarse one refined (a welded seam keeps each panel's own coordinates)."""
    faces = mesh.faces.numpy()
    n = mesh.num_vertices
    edges, side = edge_index(faces)
    ne = len(edges)
    mid = n + side  # [F,3] midpoint vertex of sides (ab, bc, ca)
    a, b, c = faces[:, 0], faces[:, 1], faces[:, 2]
    ab, bc, ca = mid[:, 0], mid[:, 1], mid[:, 2]
    fine_faces = np.concatenate([
        np.stack([a, ab, ca], 1), np.stack([ab, b, bc], 1), np.stack([ca, bc, c], 1), np.stack([ab, bc, ca], 1),
    ])
    rows = np.concatenate([np.arange(n), np.repeat(np.arange(n, n + ne), 2)])
    cols = np.concatenate([np.arange(n), edges.reshape(-1)])
    vals = np.concatenate([np.ones(n), np.full(2 * ne, 0.5)])
    U = sp.csr_matrix((vals, (rows, cols)), shape=(n + ne, n))
    x = U @ mesh.x.numpy()
    uv = U @ mesh.uv.numpy()
    face_uv = None
    if mesh.face_uv is not None:
        cu = mesh.face_uv.numpy()
        m_ab, m_bc, m_ca = 0.5 * (cu[:, 0] + cu[:, 1]), 0.5 * (cu[:, 1] + cu[:, 2]), 0.5 * (cu[:, 2] + cu[:, 0])
        face_uv = np.concatenate([
            np.stack([cu[:, 0], m_ab, m_ca], 1), np.stack([m_ab, cu[:, 1], m_bc], 1),
            np.stack([m_ca, m_bc, cu[:, 2]], 1), np.stack([m_ab, m_bc, m_ca], 1),
        ])
    fine = ClothMesh(torch.from_numpy(x), torch.from_numpy(uv), torch.from_numpy(fine_faces.astype(np.int64)),
                     name=f"{mesh.name}-fine", face_uv=None if face_uv is None else torch.from_numpy(face_uv))
    return fine, U


def subdivide_stitches(stitches: np.ndarray, coarse_edges: np.ndarray, num_coarse: int) -> np.ndarray:
    """Stitches of a subdivided mesh: the coarse pairs plus, for every pair of coarse edges
    (a, c) and (b, d) whose ends are stitched a-b and c-d, their midpoints."""
    if len(stitches) == 0:
        return stitches.reshape(0, 2)
    key = coarse_edges[:, 0] * num_coarse + coarse_edges[:, 1]
    partner = np.full(num_coarse, -1)
    partner[stitches[:, 0]] = stitches[:, 1]
    partner[stitches[:, 1]] = stitches[:, 0]
    pa, pc = partner[coarse_edges[:, 0]], partner[coarse_edges[:, 1]]
    ok = (pa >= 0) & (pc >= 0)
    lo, hi = np.minimum(pa, pc), np.maximum(pa, pc)
    other_key = lo * num_coarse + hi
    order = np.argsort(key)
    pos = np.searchsorted(key[order], other_key)
    pos = np.clip(pos, 0, len(key) - 1)
    hit = ok & (key[order][pos] == other_key)
    e1 = np.nonzero(hit)[0]
    e2 = order[pos[hit]]
    keep = e1 < e2  # each pair once
    extra = np.stack([num_coarse + e1[keep], num_coarse + e2[keep]], 1)
    return np.concatenate([stitches, extra]).astype(np.int64)


# ---------------------------------------------------------------------------- embedding

def locate_in_triangles(points: np.ndarray, point_panel: np.ndarray, tri_uv: np.ndarray, tri_panel: np.ndarray,
                        tri_vertices: np.ndarray, num_columns: int, candidates: int = 8,
                        max_outside: float = 0.5) -> sp.csr_matrix:
    """Barycentric embedding of material points in a triangulation of the same pattern:
    row i of the returned [M, num_columns] matrix holds the barycentric weights of point i
    (material coordinates `points[i]`, pattern piece `point_panel[i]`) in the triangle of
    its piece that contains it, on that triangle's vertices `tri_vertices` [F,3]. A point
    marginally outside every triangle (a curved outline discretised coarser) takes the
    nearest one with clamped weights; one further outside than `max_outside` (in units of
    barycentric coordinates) means the two triangulations are not of the same pattern."""
    rows, cols, vals = [], [], []
    for panel in np.unique(point_panel):
        sel = np.nonzero(point_panel == panel)[0]
        tris = np.nonzero(tri_panel == panel)[0]
        if len(tris) == 0:
            raise SceneError(f"pattern piece {int(panel)} has points but no triangles on the other level")
        tri = tri_uv[tris]
        k = min(candidates, len(tris))
        _, cand = cKDTree(tri.mean(1)).query(points[sel], k=k)
        cand = cand.reshape(len(sel), k)
        bary = _barycentric(tri[cand], points[sel][:, None, :])  # [M,k,3]
        outside = np.maximum(-bary, 0.0).sum(-1)
        best = np.argmin(outside, 1)
        r = np.arange(len(sel))
        if outside[r, best].max() > max_outside:
            i = int(sel[np.argmax(outside[r, best])])
            raise SceneError(f"material point {i} ({points[i].round(4).tolist()}) lies outside the other level's "
                             "pattern; the two levels must triangulate the same pattern")
        w = np.clip(bary[r, best], 0.0, None)
        w /= w.sum(1, keepdims=True)
        rows.append(np.repeat(sel, 3))
        cols.append(tri_vertices[tris[cand[r, best]]].ravel())
        vals.append(w.ravel())
    U = sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                      shape=(len(points), num_columns))
    U.eliminate_zeros()
    return U


def vertex_corners(faces: np.ndarray, num_vertices: int) -> tuple[np.ndarray, np.ndarray]:
    """One (face, corner) per vertex: where each vertex's material coordinates are read."""
    flat = faces.reshape(-1)
    first = np.full(num_vertices, -1)
    order = np.arange(len(flat))[::-1]
    first[flat[order]] = order  # the last write wins: the first occurrence
    if (first < 0).any():
        raise SceneError(f"vertex {int(np.nonzero(first < 0)[0][0])} belongs to no face")
    return first // 3, first % 3


def embedding_operator(coarse: ClothMesh, fine: ClothMesh, coarse_panel: np.ndarray | None = None,
                       fine_panel: np.ndarray | None = None) -> sp.csr_matrix:
    """Barycentric upsampling U [N_fine, N_coarse] between two triangulations of the same
    pattern: each fine vertex is located, by its material coordinates (per face corner
    for garments, with `*_panel` the pattern piece of every face), in a coarse triangle."""
    cf, ff = coarse.faces.numpy(), fine.faces.numpy()
    coarse_panel = np.zeros(len(cf), np.int64) if coarse_panel is None else np.asarray(coarse_panel)
    fine_panel = np.zeros(len(ff), np.int64) if fine_panel is None else np.asarray(fine_panel)
    face, corner = vertex_corners(ff, fine.num_vertices)
    points = fine.corner_uv().numpy()[face, corner]
    return locate_in_triangles(points, fine_panel[face], coarse.corner_uv().numpy(), coarse_panel, cf,
                               coarse.num_vertices)


def _barycentric(tri: np.ndarray, p: np.ndarray) -> np.ndarray:
    a, b, c = tri[..., 0, :], tri[..., 1, :], tri[..., 2, :]
    v0, v1, v2 = b - a, c - a, p - a
    det = v0[..., 0] * v1[..., 1] - v0[..., 1] * v1[..., 0]
    l1 = (v2[..., 0] * v1[..., 1] - v2[..., 1] * v1[..., 0]) / det
    l2 = (v0[..., 0] * v2[..., 1] - v0[..., 1] * v2[..., 0]) / det
    return np.stack([1 - l1 - l2, l1, l2], -1)


def vertex_frames(X: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """[N, 3, 3] orthonormal frames (columns: tangent, bitangent, normal) at mesh vertices:
    the area-weighted normal and the direction to a fixed neighbour projected off it."""
    n = area_vertex_normals(X, faces)
    neighbour = np.arange(len(X))
    for k in range(3):
        neighbour[faces[:, k]] = faces[:, (k + 1) % 3]
    t = X[neighbour] - X
    t -= (t * n).sum(1, keepdims=True) * n
    t /= np.maximum(np.linalg.norm(t, axis=1, keepdims=True), 1e-12)
    return np.stack([t, np.cross(n, t), n], -1)


def carry_detail(hier: "Hierarchy", x_fine: np.ndarray, X_coarse: np.ndarray) -> np.ndarray | None:
    """The fine cloth's detail over the coarse one, d = x - U X, stored per entry of U in
    the frame of that entry's coarse vertex (so that `upsample_positions` rotates it with
    the coarse cloth and blends it like linear-blend skinning). None when there is none."""
    d = x_fine - hier.upsample(X_coarse)
    if np.abs(d).max() < 1e-9:
        return None
    U = hier.U.tocoo()
    frames = vertex_frames(X_coarse, hier.coarse.model.faces.numpy())
    return np.einsum("kji,kj->ki", frames[U.col], d[U.row])


# ---------------------------------------------------------------------------- levels

@dataclass
class Hierarchy:
    """A coarse and a fine scene of the same cloth with the upsampling operator between
    them. `coarse_dt` may be a whole multiple `dt_ratio` of the fine dt."""

    coarse: Scene
    fine: Scene
    U: sp.csr_matrix
    kind: str
    dt_ratio: int = 1
    obstacle_proxies: list = field(default_factory=list)  # `proxy.proxy_obstacle` infos of the coarse level
    detail: np.ndarray | None = None  # [nnz(U), 3] fine detail in coarse vertex frames (`carry_detail`)
    _restrict: object | None = field(default=None, repr=False, compare=False)

    def __getstate__(self) -> dict:
        state = dict(self.__dict__)
        state["_restrict"] = None  # SuperLU factors do not pickle; rebuilt on first use
        return state

    @property
    def fine_mass(self) -> np.ndarray:
        """Lumped vertex masses of the fine level (kg), the metric of the restriction."""
        return self.fine.model.mass().detach().numpy()

    def upsample(self, X: np.ndarray) -> np.ndarray:
        """u(X) = U X for coarse positions or velocities [N_c,3] -> [N_f,3]."""
        return np.asarray(self.U @ X)

    def upsample_positions(self, X: np.ndarray, keep: np.ndarray | None = None) -> np.ndarray:
        """u(X) for coarse positions: U X plus the detail the fine cloth had over the coarse
        one at the start, carried in the coarse vertices' local frames (`carry_detail`; the
        coarse garment rides further off the body and has no wrinkles), scaled per fine
        vertex by `keep` (default 1). Velocities and differences of positions use the
        linear `upsample`."""
        x = self.upsample(X)
        if self.detail is None:
            return x
        U = self.U.tocoo()
        rotated = np.einsum("kij,kj->ki", vertex_frames(X, self.coarse.model.faces.numpy())[U.col], self.detail)
        weight = U.data if keep is None else U.data * keep[U.row]
        np.add.at(x, U.row, weight[:, None] * rotated)
        return x

    def coarse_part(self, X: np.ndarray, keep: np.ndarray | None = None) -> np.ndarray:
        """R u(X): the coarse-scale part of the detailed upsampling of coarse positions, the
        target that recovery's tracking holds the fine positions to."""
        return self.restrict(self.upsample_positions(X, keep))

    def coarse_state_of(self, x: np.ndarray, iterations: int = 4) -> np.ndarray:
        """Coarse positions X whose detailed upsampling has the coarse-scale part of fine
        positions x (R u(X) = R x, by fixed-point iteration from X = R x)."""
        target = self.restrict(x)
        X = target.copy()
        for _ in range(iterations if self.detail is not None else 0):
            X = X + target - self.coarse_part(X)
        return X

    def restrict(self, x: np.ndarray) -> np.ndarray:
        """R x = (U^T M U)^-1 U^T M x: the coarse-scale part of fine positions/velocities."""
        mass = self.fine_mass
        if self._restrict is None:
            self._restrict = spla.splu((self.U.T @ sp.diags(mass) @ self.U).tocsc())
        rhs = self.U.T @ (mass[:, None] * x)
        return self._restrict.solve(np.ascontiguousarray(rhs))

    def track(self, x: np.ndarray, target: np.ndarray) -> np.ndarray:
        """Tracking projection x + U (target - R x): the mass-weighted closest fine state
        whose coarse-scale part is `target` (TRACKS, Bergou et al. 2007, constraint R x = X)."""
        return x + self.upsample(target - self.restrict(x))

    def fingerprint(self) -> str:
        """Hash of both levels' geometry, time steps and durations (checkpoints match it)."""
        h = hashlib.sha1()
        for sc in (self.coarse, self.fine):
            m = sc.model
            held = [h.vertices.numpy() for h in m.handles]
            for arr in (m.mesh.x.numpy(), m.faces.numpy(), m.mesh.corner_uv().numpy(), m.pinned.numpy(), *held):
                h.update(np.ascontiguousarray(arr).tobytes())
            h.update(repr((sc.dt, sc.duration, sc.frame_time, m.fabric.name, m.obstacles.num_vertices,
                           [hd.stiffness for hd in m.handles], m.wind.implicit)).encode())
        h.update(repr((self.kind, self.dt_ratio)).encode())
        return h.hexdigest()[:16]


def _model_on(model: ClothModel, mesh: ClothMesh, stitches: np.ndarray, pins: list[PinGroup] | None = None,
              obstacles: list | None = None) -> ClothModel:
    """`model`'s fabric, pins, forces, obstacles and contact settings on another mesh of the
    same cloth (pins keep their vertex indices unless given: with subdivision, coarse vertex
    i is fine vertex i)."""
    if model.regions:
        raise SceneError("time-parallel simulation does not carry material regions (prints, patches) to other "
                         "meshes yet; run without --parallel")
    handles = []
    if pins is None:
        pins = [PinGroup(p.vertices.clone(), p.motion) for p in model.pins]
        handles = [SoftHandle(h.vertices.clone(), h.stiffness, h.motion) for h in model.handles]
    elif model.handles:
        raise SceneError("time-parallel simulation does not carry soft handles to a coarser mesh yet; "
                         "use pins, or run without --parallel")
    return ClothModel(
        mesh, model.fabric, pins=pins, handles=handles, gravity=tuple(model.gravity.tolist()),
        wind=dataclasses.replace(model.wind),
        obstacles=list(model.obstacles.obstacles if obstacles is None else obstacles), collision=copy.copy(model.collision), damping=model.damping,
        stitches=torch.from_numpy(np.asarray(stitches, np.int64).reshape(-1, 2)), stitch_stiffness=model.stitch_stiffness,
        air_damping=model.air_damping,
    )


def _with_dt(scene: Scene, model: ClothModel, dt: float, name: str) -> Scene:
    """The scene with another cloth (its origin kept only when the cloth is the scene's own)."""
    return Scene(name=name, model=model, dt=dt, duration=scene.duration, frame_time=scene.frame_time,
                 options=copy.copy(scene.options), description=scene.description, spec=scene.spec,
                 origin=scene.origin if model is scene.model else None)


LEVELS = ("auto", "coarsen", "subdivide")


GRID_FACTOR = 2.0
# The coarse garment is its pattern at 2.5x the fine edge length, but its edges stay within
# COARSE_GARMENT_EDGE (a coarser garment's chords cut deep into the body) and at least
# 1.5x the fine ones; it steps four fine steps at once against the body near it. Measured
# on the bench walk (1 cm T-shirt): 1304 coarse vertices for 8201 fine ones and K 13,
# against 3646 and K 3.7 at 1.5x and two fine steps (docs/PARALLEL.md).
GARMENT_FACTOR, GARMENT_MIN_FACTOR, COARSE_GARMENT_EDGE = 2.5, 1.5, 0.045
GARMENT_DT_RATIO = 4


def garment_factor(edge_length: float) -> float:
    """The default coarsening factor of a garment triangulated at `edge_length` (m)."""
    return min(GARMENT_FACTOR, max(GARMENT_MIN_FACTOR, COARSE_GARMENT_EDGE / edge_length))


def build_hierarchy(scene: Scene, level: str = "auto", factor: float | None = None, dt_ratio: int | None = None,
                    obstacle_cell: float | str | None = "auto") -> Hierarchy:
    """Two levels of a scene's cloth.

    `level="coarsen"`: the scene's cloth is the fine level (the output has the serial run's
    format) and the coarse level triangulates the same pattern `factor` times coarser: a
    grid at 1/factor of the resolution, or a garment animation's sewing pattern at factor
    times the drape's edge length. `level="subdivide"`: the scene's cloth is the coarse
    level and the fine one its midpoint subdivision (exact linear upsampling; any mesh).
    `"auto"` coarsens when it can and subdivides otherwise. `factor` defaults to 2 for
    grids and to `garment_factor` of the drape's edge length for garments. The fine level
    runs at the scene's dt, the coarse one at `dt_ratio` times it (None: `GARMENT_DT_RATIO`
    for garment animations, 1 otherwise).
    `obstacle_cell` (m) replaces the coarse garment's body by a decimated, inflated proxy
    near the garment (`tryon.parallel.proxy`; e.g. 0.03, which measured worse: see
    docs/PARALLEL.md); "auto" (and "crop") keeps the real body's triangles within
    `proxy.CROP_REACH` of the garment, unchanged; None the whole body."""
    if obstacle_cell not in (None, "auto", "crop") and not float(obstacle_cell) > 0:
        raise SceneError(f"the coarse obstacle cell size must be positive, got {obstacle_cell}")
    garment = isinstance(scene.origin, PatternOrigin)
    if dt_ratio is None:
        dt_ratio = GARMENT_DT_RATIO if garment else 1
    if dt_ratio < 1 or int(dt_ratio) != dt_ratio:
        raise SceneError(f"the coarse time step must be a whole multiple of the fine one, got ratio {dt_ratio}")
    if level not in LEVELS:
        raise SceneError(f"unknown hierarchy level {level!r}; use one of {', '.join(LEVELS)}")
    grid = isinstance(scene.origin, GridOrigin)
    if level == "auto":
        level = "coarsen" if garment or grid else "subdivide"
    if level == "subdivide":
        fine_model, U = _subdivided(scene.model)
        fine_scene = _with_dt(scene, fine_model, scene.dt, scene.name)
        coarse_scene = _with_dt(scene, scene.model, scene.dt * dt_ratio, f"{scene.name}-coarse")
        return Hierarchy(coarse_scene, fine_scene, U, "subdivide", int(dt_ratio))
    if factor is None:
        factor = garment_factor(scene.origin.edge_length) if garment else GRID_FACTOR
    factor = float(factor)
    if not factor > 1.0:
        raise SceneError(f"the coarsening factor must be larger than 1, got {factor}")
    proxies: list = []
    if garment:
        cell = "crop" if obstacle_cell == "auto" else obstacle_cell
        coarse_model, U, proxies = _coarser_garment(scene, factor, cell)
    elif grid:
        coarse_model, U = _coarser_grid(scene, factor)
    else:
        raise SceneError(f"scene {scene.name}: only grid cloths and garment animations can be coarsened; "
                         "use the 'subdivide' hierarchy (the scene's cloth as the coarse level)")
    coarse_scene = _with_dt(scene, coarse_model, scene.dt * dt_ratio, f"{scene.name}-coarse")
    hier = Hierarchy(coarse_scene, scene, U, f"coarsen:{factor:g}", int(dt_ratio), proxies)
    hier.detail = carry_detail(hier, scene.model.mesh.x.numpy(), coarse_model.mesh.x.numpy())
    return hier


def _subdivided(model: ClothModel) -> tuple[ClothModel, sp.csr_matrix]:
    edges = model.mesh.edges.numpy()
    mesh, U = subdivide_mesh(model.mesh)
    stitches = subdivide_stitches(model.stitches.numpy(), edges, model.num_vertices)
    return _model_on(model, mesh, stitches), U


def _coarser_grid(scene: Scene, factor: float) -> tuple[ClothModel, sp.csr_matrix]:
    spec = scene.spec
    grid = spec["cloth"]["grid"] or {}
    res = grid.get("resolution", [32, 32])
    res = [res, res] if isinstance(res, int) else [int(r) for r in res]
    coarse_res = [max(3, int(round((r - 1) / factor)) + 1) for r in res]
    if coarse_res == res:
        raise SceneError(f"a {res[0]}x{res[1]} grid is too small to coarsen by {factor}; use a finer grid or 'subdivide'")
    pins = spec["cloth"].get("pins") or []
    if not all(isinstance(v, str) for v in pins):
        raise SceneError("a coarsened grid maps pins by corner name only; use the 'subdivide' hierarchy for pins by index")
    for h in spec["cloth"].get("handles") or []:
        if not all(isinstance(v, str) for v in h.get("vertices", [])):
            raise SceneError("a coarsened grid maps handles by corner name only; use the 'subdivide' hierarchy")
    coarse_spec = copy.deepcopy(spec)
    coarse_spec["cloth"]["grid"]["resolution"] = coarse_res
    coarse = parse_scene(coarse_spec, default_name=scene.name).model
    model = _model_on(scene.model, coarse.mesh, np.zeros((0, 2), np.int64), pins=coarse.pins)
    return model, embedding_operator(model.mesh, scene.model.mesh)


def _coarser_garment(scene: Scene, factor: float, cell: float | None) -> tuple[ClothModel, sp.csr_matrix, list]:
    """The coarse level of a garment (a scene whose cloth has a `PatternOrigin`): its
    sewing pattern at `factor` times its edge length, colliding with body proxies of
    `cell` metres ("crop": the body near the garment; None: the whole body)."""
    from tryon.parallel.proxy import coarse_obstacles

    if len(scene.model.stitches) or len(scene.model.pins):
        raise SceneError("a coarsened garment cannot carry open stitches or pins; use the 'subdivide' hierarchy")
    origin = scene.origin
    fine_mesh = scene.model.mesh
    if len(origin.face_panel) != fine_mesh.faces.shape[0]:
        raise SceneError(f"scene {scene.name}: its pattern origin has {len(origin.face_panel)} faces, the cloth "
                         f"{fine_mesh.faces.shape[0]}")
    fine_panel = np.asarray(origin.face_panel)
    mesh, coarse_panel = coarsen_garment(fine_mesh, fine_panel, origin.remesh(origin.edge_length * factor))
    obstacles, proxies = coarse_obstacles(scene.model.obstacles.obstacles, cell, near=fine_mesh.x.numpy())
    probe = _model_on(scene.model, mesh, np.zeros((0, 2), np.int64), pins=[], obstacles=obstacles)
    mesh = _clear_of_obstacles(mesh, probe)
    frozen = [Obstacle(o.name, o.vertices_at(0.0), o.faces) for o in obstacles]
    mesh = settle_at_start(_model_on(scene.model, mesh, np.zeros((0, 2), np.int64), pins=[], obstacles=frozen),
                           scene.dt, scene.options)
    model = _model_on(scene.model, mesh, np.zeros((0, 2), np.int64), pins=[], obstacles=obstacles)
    return model, embedding_operator(mesh, fine_mesh, coarse_panel, fine_panel), proxies


SETTLE_STEPS = 30


def settle_at_start(model: ClothModel, dt: float, options: StepOptions | None = None, steps: int = SETTLE_STEPS,
                    keep_velocity: float = 0.5) -> ClothMesh:
    """The coarse garment let come to rest on `model`'s obstacles (the body frozen as it is
    at t = 0; the fine garment starts from its drape, at rest): without this the coarse
    run spends its first steps falling from where `_clear_of_obstacles` put it, and every
    segment inherits that motion. Velocities are damped by `keep_velocity` each step."""
    def damp(s: ClothState) -> ClothState:
        return ClothState(s.x, s.v * keep_velocity, s.t)

    outcome = run(ImplicitEulerSolver(model, options), model.initial_state(), dt, until=steps, after_step=damp)
    state = outcome.state
    m = model.mesh
    return ClothMesh(state.x.detach().clone(), m.uv, m.faces, m.name, face_uv=m.face_uv)


def _clear_of_obstacles(mesh: ClothMesh, model: ClothModel, steps: tuple = (1, 1.5, 2, 3, 4, 6, 8, 12)) -> ClothMesh:
    """The coarse garment's vertices lie on the fine one, but its longer edges are chords
    that cut into a curved body. Vertices nearer the obstacles than a gap (from the contact
    thickness up) move out along the obstacle normal, with the smallest gap that leaves no
    cloth-obstacle intersection."""
    from tryon.sim import geometry as geo

    ob = model.obstacles.vertices_at(0.0)
    if len(ob) == 0:
        return mesh
    faces, edges = mesh.faces.numpy(), mesh.edges.numpy()
    h = model.collision.thickness

    verdict = {"clear": False}

    def clear(x: np.ndarray) -> bool:
        _, crossing = geo.count_intersections(x, faces, edges, ob, model.obstacles.faces, model.obstacles.edges,
                                              self_collision=False)
        verdict["clear"] = crossing == 0
        return verdict["clear"]

    x, _, _ = geo.push_outside(mesh.x.numpy(), ob, model.obstacles.faces, [k * h for k in steps], accept=clear)
    if verdict["clear"]:  # the verdict on the gap push_outside settled on
        return ClothMesh(torch.from_numpy(x), mesh.uv, mesh.faces, mesh.name, face_uv=mesh.face_uv)
    raise SceneError(f"the coarse garment still cuts into the obstacles {steps[-1] * h * 100:.1f} cm off them; "
                     "use a smaller coarsening factor")


def coarsen_garment(fine: ClothMesh, fine_panel: np.ndarray, coarse: PatternMesh) -> tuple[ClothMesh, np.ndarray]:
    """The garment's pattern triangulated coarser (`coarse`, seams welded), each vertex
    placed on the (draped) `fine` garment at its material point. Returns the mesh and the
    pattern piece of each of its faces (`fine_panel` is that of the fine faces)."""
    faces, corner_uv, coarse_panel = coarse.faces, coarse.corner_uv, coarse.face_panel
    n = coarse.num_vertices
    face, corner = vertex_corners(faces, n)
    uv = corner_uv[face, corner]
    E = locate_in_triangles(uv, coarse_panel[face], fine.corner_uv().numpy(), np.asarray(fine_panel),
                            fine.faces.numpy(), fine.num_vertices)
    x = E @ fine.x.numpy()
    mesh = ClothMesh(torch.from_numpy(x), torch.from_numpy(uv), torch.from_numpy(faces.astype(np.int64)),
                     name=f"{fine.name}-coarse", face_uv=torch.from_numpy(corner_uv))
    return mesh, coarse_panel
