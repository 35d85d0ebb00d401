"""What a simulation run holds: `ClothModel` (does not change during a run), `ClothState`
(changes every step) and `Control` (per-step inputs). Split as in Newton's Model/State/
Control so that stepping, differentiation, checkpoints and time-parallel segments all see
the same small objects."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import torch

from tryon.errors import SceneError
from tryon.fabric.base import Fabric
from tryon.sim.forces.bending import hinge_rest_data_corners
from tryon.sim.forces.geometry import build_hinges, rest_state
from tryon.sim.mesh import DTYPE, ClothMesh
from tryon.sim.obstacles import Motion, Obstacle, ObstacleSet


@dataclass
class Wind:
    """Uniform wind (m/s) acting through ARCSim's face drag model. `implicit`: its velocity
    Jacobian (a damping) enters the implicit solve; False adds the force explicitly, as
    ARCSim does (``physics.cpp``: no Jacobian for wind)."""

    velocity: tuple[float, float, float] = (0.0, 0.0, 0.0)
    density: float = 1.0
    drag: float = 0.0
    implicit: bool = True


@dataclass
class CollisionSettings:
    """Contact parameters. `thickness` (m) is the proximity distance kept between surfaces;
    `stiffness` (N/m per m^2 of cloth area, ARCSim's collision_stiffness) scales the
    repulsion penalty; `friction` is the Coulomb coefficient for cloth-obstacle contact and
    `self_friction` between cloth layers."""

    thickness: float = 0.005
    stiffness: float = 1.0e6
    friction: float = 0.3
    self_friction: float = 0.3
    self_collision: bool = True
    enabled: bool = True


@dataclass
class PinGroup:
    """Vertices attached to a handle that follows `motion` from their rest positions."""

    vertices: torch.Tensor
    motion: Motion = field(default_factory=Motion)


@dataclass
class SoftHandle:
    """Vertices pulled towards their rest positions (moved by `motion`) by a quadratic
    penalty of `stiffness` N/m per axis, integrated implicitly: ARCSim's node handles
    (``handle.cpp``, ``constraint.cpp``: ``EqCon``, ``magic.handle_stiffness``), which let a
    pinned corner drift by a few millimetres under load. A hard `PinGroup` does not."""

    vertices: torch.Tensor
    stiffness: float
    motion: Motion = field(default_factory=Motion)


@dataclass
class MaterialRegion:
    """Part of the cloth made of more than the fabric (a screen print, a patch): its faces
    [k], multipliers of the fabric's membrane and bending stiffness there, and the areal
    density it adds (kg/m^2). Overlapping regions multiply stiffness and add density."""

    faces: torch.Tensor
    stretch_scale: float = 1.0
    bend_scale: float = 1.0
    added_density: float = 0.0  # kg/m^2
    name: str = "region"


@dataclass
class ClothState:
    x: torch.Tensor
    v: torch.Tensor
    t: float = 0.0

    def clone(self) -> "ClothState":
        return ClothState(self.x.clone(), self.v.clone(), self.t)


@dataclass
class Control:
    """Per-step inputs: extra forces on vertices (N), a wind override (m/s), and overrides
    of settings that a process ramps during a run: the stitches' stiffness (N/m; sewing
    pulls them tighter step by step), the cloth-obstacle friction coefficient (a drape
    lets the cloth slide while the body morphs) and the still-air damping (1/s; a drape
    settling towards its static equilibrium). None keeps the model's value. The
    differentiable step (tryon.diff) takes forces and wind from a Control, not these
    overrides."""

    external_force: torch.Tensor | None = None
    wind_velocity: torch.Tensor | None = None
    stitch_stiffness: float | None = None
    friction: float | None = None
    air_damping: float | None = None


class ClothModel:
    """Everything about a cloth run that is fixed: mesh, fabric, rest shape, masses,
    pins/handles, gravity, wind, obstacles and contact settings."""

    def __init__(
        self,
        mesh: ClothMesh,
        fabric: Fabric,
        pins: list[PinGroup] | None = None,
        gravity: tuple[float, float, float] = (0.0, 0.0, -9.8),
        wind: Wind | None = None,
        obstacles: list[Obstacle] | None = None,
        collision: CollisionSettings | None = None,
        damping: float = 0.0,
        stitches: torch.Tensor | None = None,
        stitch_stiffness: float = 0.0,
        air_damping: float = 0.0,
        handles: list[SoftHandle] | None = None,
        regions: list[MaterialRegion] | None = None,
    ):
        self.mesh = mesh
        self.fabric = fabric
        self.pins = pins or []
        self.gravity = torch.tensor(gravity, dtype=DTYPE)
        self.wind = wind or Wind()
        self.obstacles = ObstacleSet(obstacles or [])
        self.collision = collision or CollisionSettings()
        self.damping = float(damping)
        self.faces = mesh.faces
        self.edges = mesh.edges
        corners = mesh.corner_uv()
        F = corners.shape[0]
        self.Dm_inv, self.rest_area = rest_state(corners.reshape(-1, 2), torch.arange(3 * F).reshape(F, 3))
        self.hinges, self.hinge_faces = build_hinges(mesh.faces, return_faces=True)
        hd = hinge_rest_data_corners(corners, mesh.faces, self.hinges, self.hinge_faces)
        self.hinge_rest_theta = hd["rest_theta"]
        self.hinge_area_sum = hd["area_sum"]
        self.hinge_edge_dir_uv = hd["edge_dir_uv"]
        self.vertex_area = self._vertex_areas()
        self.pinned = self._pinned_indices()
        self.handles = handles or []
        self._check_handles()
        self.stitches = self._checked_stitches(stitches)
        self.stitch_stiffness = float(stitch_stiffness)
        self.air_damping = float(air_damping)  # 1/s: force -c m v (still air, e.g. while sewing)
        self.regions = list(regions or [])
        self.face_stretch_scale, self.hinge_bend_scale, self.added_mass = self._region_fields()

    def _region_fields(self) -> tuple[torch.Tensor | None, torch.Tensor | None, torch.Tensor | None]:
        """Per-face stretch multipliers [F], per-hinge bend multipliers [H] (the mean of its
        two faces') and added vertex masses [V] of the material regions (None: no regions)."""
        if not self.regions:
            return None, None, None
        F = self.faces.shape[0]
        stretch = torch.ones(F, dtype=DTYPE)
        bend = torch.ones(F, dtype=DTYPE)
        density = torch.zeros(F, dtype=DTYPE)
        for k, r in enumerate(self.regions):
            idx = torch.as_tensor(np.asarray(r.faces), dtype=torch.int64).reshape(-1)
            r.faces = idx
            if len(idx) and (int(idx.min()) < 0 or int(idx.max()) >= F):
                raise SceneError(f"material region {r.name!r}: face indices must lie in [0, {F - 1}]")
            for what, value, low in (("stretch_scale", r.stretch_scale, 0.0), ("bend_scale", r.bend_scale, 0.0)):
                if not (np.isfinite(value) and value > low):
                    raise SceneError(f"material region {r.name!r}: {what} must be a positive number, got {value}")
            if not (np.isfinite(r.added_density) and r.added_density >= 0):
                raise SceneError(f"material region {r.name!r}: added_density must be >= 0 kg/m^2, got {r.added_density}")
            stretch[idx] *= float(r.stretch_scale)
            bend[idx] *= float(r.bend_scale)
            density[idx] += float(r.added_density)
        added = torch.zeros(self.mesh.num_vertices, dtype=DTYPE)
        added.index_add_(0, self.faces.reshape(-1), (density * self.rest_area / 3).repeat_interleave(3))
        return stretch, bend[self.hinge_faces].mean(1), added

    def stretching_law(self, law):
        """`law` (G [F,3] -> k [F,4], a fabric's membrane stiffness) with the regions' multipliers."""
        if self.face_stretch_scale is None:
            return law
        scale = self.face_stretch_scale
        return lambda G: law(G) * scale[:, None]

    def bending_law(self, law):
        """`law` (alpha [H], edge_dir_uv [H,2] -> ke [H]) with the regions' multipliers."""
        if self.hinge_bend_scale is None:
            return law
        scale = self.hinge_bend_scale
        return lambda alpha, d: law(alpha, d) * scale

    def _checked_stitches(self, stitches) -> torch.Tensor:
        """Vertex pairs [S,2] pulled together by zero-length springs (sewing seams)."""
        if stitches is None:
            return torch.zeros((0, 2), dtype=torch.int64)
        st = torch.as_tensor(stitches, dtype=torch.int64)
        n = self.mesh.num_vertices
        if st.ndim != 2 or st.shape[1] != 2 or (len(st) and (int(st.min()) < 0 or int(st.max()) >= n)):
            raise SceneError(f"stitches must be vertex index pairs [S,2] in [0, {n - 1}]")
        if len(st) and bool((st[:, 0] == st[:, 1]).any()):
            raise SceneError("a stitch joins a vertex to itself")
        return st

    def _vertex_areas(self) -> torch.Tensor:
        n = self.mesh.num_vertices
        area = torch.zeros(n, dtype=DTYPE)
        area.index_add_(0, self.faces.reshape(-1), (self.rest_area / 3).repeat_interleave(3))
        return area

    def _pinned_indices(self) -> torch.Tensor:
        if not self.pins:
            return torch.zeros(0, dtype=torch.int64)
        idx = torch.cat([p.vertices for p in self.pins])
        n = self.mesh.num_vertices
        if len(idx) and (int(idx.min()) < 0 or int(idx.max()) >= n):
            raise SceneError(f"pinned vertex indices must lie in [0, {n - 1}]")
        if len(torch.unique(idx)) != len(idx):
            raise SceneError("a vertex is pinned by more than one handle")
        return idx

    def _check_handles(self) -> None:
        n = self.mesh.num_vertices
        pinned = set(self.pinned.tolist())
        seen: set[int] = set()
        for k, h in enumerate(self.handles):
            idx = torch.as_tensor(h.vertices, dtype=torch.int64).reshape(-1)
            h.vertices = idx
            if len(idx) and (int(idx.min()) < 0 or int(idx.max()) >= n):
                raise SceneError(f"soft handle {k}: vertex indices must lie in [0, {n - 1}]")
            if not (np.isfinite(h.stiffness) and h.stiffness > 0):
                raise SceneError(f"soft handle {k}: stiffness must be a positive number of N/m, got {h.stiffness}")
            if pinned & set(idx.tolist()):
                raise SceneError(f"soft handle {k}: a vertex is both pinned and held by a soft handle")
            if len(set(idx.tolist())) != len(idx) or seen & set(idx.tolist()):
                raise SceneError(f"soft handle {k}: a vertex is held by more than one soft handle")
            seen |= set(idx.tolist())

    def handle_springs(self, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The soft handles at time t: vertex indices [h], stiffness per vertex [h] (N/m)
        and target positions [h, 3] (numpy)."""
        if not self.handles:
            return np.zeros(0, np.int64), np.zeros(0), np.zeros((0, 3))
        idx, k, tgt = [], [], []
        for h in self.handles:
            rest = self.mesh.x[h.vertices].numpy()
            idx.append(h.vertices.numpy())
            k.append(np.full(len(h.vertices), float(h.stiffness)))
            tgt.append(np.ascontiguousarray(h.motion.apply(rest, t)))
        return np.concatenate(idx).astype(np.int64), np.concatenate(k), np.concatenate(tgt)

    def mass(self, fabric: Fabric | None = None) -> torch.Tensor:
        """Lumped vertex masses (kg): areal density times a third of adjacent rest areas,
        plus what material regions add."""
        m = (fabric or self.fabric).density * self.vertex_area
        return m if self.added_mass is None else m + self.added_mass

    def pin_targets(self, t: float) -> torch.Tensor:
        """World positions [k,3] of the pinned vertices at time t (handles follow their motion)."""
        if not self.pins:
            return torch.zeros((0, 3), dtype=DTYPE)
        parts = []
        for group in self.pins:
            rest = self.mesh.x[group.vertices].numpy()
            parts.append(torch.from_numpy(np.ascontiguousarray(group.motion.apply(rest, t))))
        return torch.cat(parts)

    def initial_state(self) -> ClothState:
        return ClothState(self.mesh.x.clone(), torch.zeros_like(self.mesh.x), 0.0)

    @property
    def num_vertices(self) -> int:
        return self.mesh.num_vertices
