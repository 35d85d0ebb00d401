"""Kinematic collision obstacles: spheres, boxes, planes, pyramids and triangle meshes.

Every obstacle is a triangle mesh with outward normals whose vertices follow a prescribed
motion. The simulator merges all obstacles into one triangle soup per time step
(`ObstacleSet.vertices_at(t)`), so collision code has one path for every shape.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
import numpy as np
import trimesh

from tryon.errors import SceneError
from tryon.sim.geometry.normals import mesh_edges


@dataclass
class Motion:
    """Rigid motion about `pivot`: translation velocity (m/s) and rotation (axis, deg/s).

    Alternatively `keyframes` [K,M,3] with `keyframe_times` [K] give per-vertex positions
    that are linearly interpolated (clamped at the ends) - a body that moves between frames.
    `start`/`stop` (s) limit the rigid motion to a time window.
    """

    velocity: np.ndarray = field(default_factory=lambda: np.zeros(3))
    angular_velocity_deg: float = 0.0
    axis: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, 1.0]))
    pivot: np.ndarray = field(default_factory=lambda: np.zeros(3))
    start: float = 0.0
    stop: float = float("inf")
    keyframes: np.ndarray | None = None
    keyframe_times: np.ndarray | None = None

    def is_static(self) -> bool:
        moving = np.any(self.velocity != 0) or self.angular_velocity_deg != 0
        return self.keyframes is None and not moving

    def apply(self, rest: np.ndarray, t: float) -> np.ndarray:
        if self.keyframes is not None:
            return _interpolate_keyframes(self.keyframes, self.keyframe_times, t)
        tau = min(max(t - self.start, 0.0), self.stop - self.start)
        out = rest
        if self.angular_velocity_deg != 0:
            angle = np.deg2rad(self.angular_velocity_deg * tau)
            rot = trimesh.transformations.rotation_matrix(angle, self.axis)[:3, :3]
            out = (out - self.pivot) @ rot.T + self.pivot
        return out + self.velocity * tau


def _interpolate_keyframes(frames: np.ndarray, times: np.ndarray, t: float) -> np.ndarray:
    if t <= times[0]:
        return frames[0]
    if t >= times[-1]:
        return frames[-1]
    k = int(np.searchsorted(times, t) - 1)
    s = (t - times[k]) / (times[k + 1] - times[k])
    return (1 - s) * frames[k] + s * frames[k + 1]


@dataclass
class Obstacle:
    """A triangle mesh (outward normals) with a motion."""

    name: str
    rest_vertices: np.ndarray
    faces: np.ndarray
    motion: Motion = field(default_factory=Motion)

    def vertices_at(self, t: float) -> np.ndarray:
        return self.motion.apply(self.rest_vertices, t)


def sphere(center, radius: float, subdivisions: int = 3, name: str = "sphere", motion: Motion | None = None) -> Obstacle:
    if radius <= 0:
        raise SceneError(f"obstacle {name}: sphere radius must be positive, got {radius}")
    m = trimesh.creation.icosphere(subdivisions=subdivisions, radius=radius)
    return Obstacle(name, np.asarray(m.vertices) + np.asarray(center, float), np.asarray(m.faces, np.int64), motion or Motion())


def box(center, size, name: str = "box", motion: Motion | None = None) -> Obstacle:
    size = np.asarray(size, float)
    if np.any(size <= 0):
        raise SceneError(f"obstacle {name}: box size must be positive, got {size.tolist()}")
    m = trimesh.creation.box(extents=size)
    return Obstacle(name, np.asarray(m.vertices) + np.asarray(center, float), np.asarray(m.faces, np.int64), motion or Motion())


def plane(point, normal, size: float = 4.0, divisions: int = 8, name: str = "plane", motion: Motion | None = None) -> Obstacle:
    """A finite square patch of a plane (side `size` m), normal pointing to the free side."""
    n = np.asarray(normal, float)
    if np.linalg.norm(n) == 0:
        raise SceneError(f"obstacle {name}: plane normal must be non-zero")
    n = n / np.linalg.norm(n)
    a = np.cross(n, [1.0, 0, 0] if abs(n[0]) < 0.9 else [0, 1.0, 0])
    a /= np.linalg.norm(a)
    b = np.cross(n, a)
    s = np.linspace(-size / 2, size / 2, divisions + 1)
    ss, tt = np.meshgrid(s, s, indexing="xy")
    verts = np.asarray(point, float) + ss.ravel()[:, None] * a + tt.ravel()[:, None] * b
    idx = np.arange((divisions + 1) ** 2).reshape(divisions + 1, divisions + 1)
    p, q = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel()
    r, w = idx[1:, :-1].ravel(), idx[1:, 1:].ravel()
    faces = np.concatenate([np.stack([p, q, w], 1), np.stack([p, w, r], 1)])
    faces = _orient_faces(verts, faces, n)
    return Obstacle(name, verts, faces.astype(np.int64), motion or Motion())


def pyramid(apex, base_size: float, height: float, inverted: bool = True, name: str = "pyramid", motion: Motion | None = None) -> Obstacle:
    """A closed square pyramid. `inverted` puts the apex at the bottom (a funnel-like hopper
    seen from above is the classic cloth test; here the solid pyramid points down)."""
    if base_size <= 0 or height <= 0:
        raise SceneError(f"obstacle {name}: pyramid base_size and height must be positive")
    apex = np.asarray(apex, float)
    h = base_size / 2
    dz = -height if inverted else height
    base = apex + np.array([[-h, -h, -dz], [h, -h, -dz], [h, h, -dz], [-h, h, -dz]])
    verts = np.vstack([apex[None], base])
    faces = np.array([[0, 1, 2], [0, 2, 3], [0, 3, 4], [0, 4, 1], [1, 3, 2], [1, 4, 3]], np.int64)
    mesh = trimesh.Trimesh(verts, faces, process=False)
    trimesh.repair.fix_normals(mesh)
    return Obstacle(name, np.asarray(mesh.vertices), np.asarray(mesh.faces, np.int64), motion or Motion())


def funnel(apex, rim_size: float, height: float, name: str = "funnel", motion: Motion | None = None) -> Obstacle:
    """An open, upside-down square pyramid (apex at the bottom, no lid): the four sloped
    walls of a hopper, with normals pointing inwards to where the cloth is."""
    if rim_size <= 0 or height <= 0:
        raise SceneError(f"obstacle {name}: pyramid rim size and height must be positive")
    apex = np.asarray(apex, float)
    h = rim_size / 2
    rim = apex + np.array([[-h, -h, height], [h, -h, height], [h, h, height], [-h, h, height]])
    verts = np.vstack([apex[None], rim])
    faces = np.array([[0, 1, 2], [0, 2, 3], [0, 3, 4], [0, 4, 1]], np.int64)
    centre = apex + np.array([0.0, 0.0, height])
    e1 = verts[faces[:, 1]] - verts[faces[:, 0]]
    e2 = verts[faces[:, 2]] - verts[faces[:, 0]]
    normals = np.cross(e1, e2)
    to_axis = centre - verts[faces].mean(1)
    flip = np.sum(normals * to_axis, 1) < 0
    faces[flip] = faces[flip][:, [0, 2, 1]]
    return Obstacle(name, verts, faces, motion or Motion())


def mesh_obstacle(path: str | Path, name: str | None = None, motion: Motion | None = None) -> Obstacle:
    try:
        m = trimesh.load(str(path), force="mesh", process=False)
    except Exception as exc:  # trimesh raises many kinds of errors on bad files
        raise SceneError(f"obstacle mesh {path}: could not be read ({exc})") from exc
    if len(m.faces) == 0:
        raise SceneError(f"obstacle mesh {path}: has no triangles")
    return Obstacle(name or Path(path).stem, np.asarray(m.vertices, float), np.asarray(m.faces, np.int64), motion or Motion())


def _orient_faces(verts: np.ndarray, faces: np.ndarray, normal: np.ndarray) -> np.ndarray:
    e1 = verts[faces[:, 1]] - verts[faces[:, 0]]
    e2 = verts[faces[:, 2]] - verts[faces[:, 0]]
    flip = np.cross(e1, e2) @ normal < 0
    faces = faces.copy()
    faces[flip] = faces[flip][:, [0, 2, 1]]
    return faces


class ObstacleSet:
    """All obstacles of a scene merged into one triangle soup with fixed topology."""

    def __init__(self, obstacles: list[Obstacle]):
        self.obstacles = list(obstacles)
        offsets = np.cumsum([0] + [len(o.rest_vertices) for o in self.obstacles])
        self._offsets = offsets
        faces = [o.faces + off for o, off in zip(self.obstacles, offsets[:-1])]
        self.faces = np.concatenate(faces).astype(np.int64) if faces else np.zeros((0, 3), np.int64)
        self.edges = mesh_edges(self.faces) if len(self.faces) else np.zeros((0, 2), np.int64)
        self.static = all(o.motion.is_static() for o in self.obstacles)
        self._static_vertices = self._merge(0.0) if self.static else None

    @property
    def num_vertices(self) -> int:
        return int(self._offsets[-1])

    def _merge(self, t: float) -> np.ndarray:
        if not self.obstacles:
            return np.zeros((0, 3))
        return np.concatenate([o.vertices_at(t) for o in self.obstacles]).astype(np.float64)

    def vertices_at(self, t: float) -> np.ndarray:
        if self._static_vertices is not None:
            return self._static_vertices
        return self._merge(t)

    def per_obstacle(self, vertices: np.ndarray) -> list[tuple[str, np.ndarray, np.ndarray]]:
        """Split merged vertices back into (name, vertices, faces) per obstacle."""
        out = []
        for o, a, b in zip(self.obstacles, self._offsets[:-1], self._offsets[1:]):
            out.append((o.name, vertices[a:b], o.faces))
        return out

