"""Declarative scenes: a YAML file (or a built-in example) describing a cloth, its fabric,
pins and handles, wind, obstacles with motion, time step and duration. The full reference,
generated from the schema in `tryon.sim.scene_schema`, is docs/SCENE_FORMAT.md; the limits
of `tryon.limits` are checked before anything is built.

Example (every key but `cloth` is optional):

```yaml
name: hanging
dt: 0.01            # s
duration: 2.0       # s
frame_time: 0.04    # s between written frames
gravity: [0, 0, -9.8]
cloth:
  grid: {resolution: [32, 32], size: [1.0, 1.0], origin: [-0.5, -0.5, 1.0], orientation: horizontal}
  # or: mesh: garment.obj   (its 'vt' are material coordinates in metres)
  fabric: gray-interlock  # a preset, a fabric .json, or {preset: ..., thicken: 2} / {type: isotropic, ...}
  pins: [top-left, top-right]  # grid corners or vertex indices
  handles:            # pinned vertices that move
    - {vertices: [0, 5], motion: {velocity: [0, 0, 0.1], start: 0.0, stop: 1.0}}
wind: {velocity: [2, 2, 0], density: 1.0, drag: 0.0}
obstacles:
  - {type: sphere, center: [0, 0, 0], radius: 0.25, motion: {velocity: [0, 0, 0]}}
  - {type: box, center: [0, 0, 0], size: [1, 1, 1]}
  - {type: plane, point: [0, 0, 0], normal: [0, 0, 1], size: 4}
  - {type: pyramid, apex: [0, 0, 0], rim_size: 0.8, height: 0.5}   # open, upside-down
  - {type: mesh, path: body.obj}
collision: {thickness: 0.005, stiffness: 1.0e6, friction: 0.3, self_friction: 0.3, self_collision: true}
solver: {linear: auto, damping: 0.0, max_substep_depth: 3}
```
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from tryon.errors import InputFileError, SceneError, TryonError
from tryon.fabric import load_fabric
from tryon.limits import LIMITS, check_limit, check_run
from tryon.sim import obstacles as obs
from tryon.sim.integrator import StepOptions
from tryon.sim.mesh import ClothMesh, grid_corner, grid_mesh, mesh_from_obj
from tryon.sim.model import ClothModel, CollisionSettings, PinGroup, SoftHandle, Wind
from tryon.sim.origin import ClothOrigin, GridOrigin
from tryon.sim.scene_schema import (ClothSpec, MotionSpec, ObstacleSpec, SceneSpec, safe_name, validate_scene_spec)

TOP_KEYS = set(SceneSpec.model_fields)


@dataclass
class Scene:
    name: str
    model: ClothModel
    dt: float
    duration: float
    frame_time: float
    options: StepOptions
    description: str = ""
    spec: dict | None = None
    origin: ClothOrigin | None = None  # a grid or a pattern's triangulation (for coarsening)

    @property
    def num_steps(self) -> int:
        return max(1, int(round(self.duration / self.dt)))

    @property
    def steps_per_frame(self) -> int:
        return max(1, int(round(self.frame_time / self.dt)))


def load_scene(path: str | Path, allow_large: bool | None = None) -> Scene:
    """A scene from a YAML file (format: docs/SCENE_FORMAT.md); `allow_large` lifts the
    overridable limits of `tryon.limits`."""
    from tryon.io.safe_yaml import load_yaml

    path = Path(path)
    try:
        size = path.stat().st_size
        check_limit(f"scene file {path} (bytes)", size, LIMITS.max_yaml_bytes, "max_yaml_bytes", overridable=False)
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise SceneError(f"scene file {path}: cannot be read ({exc.strerror or exc})") from None
    except UnicodeDecodeError:
        raise SceneError(f"scene file {path}: is not UTF-8 text; save it as a UTF-8 YAML file") from None
    try:
        spec = load_yaml(text, f"scene file {path}")
    except InputFileError as exc:
        raise SceneError(str(exc)) from None
    return parse_scene(spec, base_dir=path.parent, default_name=path.stem, allow_large=allow_large,
                       source=f"scene file {path}")


def parse_scene(spec: Any, base_dir: Path | None = None, default_name: str = "scene", allow_large: bool | None = None,
                source: str = "scene") -> Scene:
    """A scene from a parsed mapping: checked against the schema and the limits before
    anything is built."""
    s = validate_scene_spec(spec, source)
    base_dir = base_dir or Path(".")
    name = s.name or safe_name(default_name)
    frame_time = s.effective_frame_time
    _check_limits(s, name, allow_large)
    mesh, corner_res = _build_cloth_mesh(s.cloth, base_dir, source)
    check_limit(f"{source}: cloth vertices", mesh.num_vertices, LIMITS.max_vertices, "max_vertices", allow_large)
    fabric = _parse_fabric(s.cloth.fabric)
    pins, handles = _parse_pins(s.cloth, mesh, corner_res)
    solver = s.solver
    model = ClothModel(
        mesh,
        fabric,
        pins=pins,
        handles=handles,
        gravity=s.gravity,
        wind=Wind(s.wind.velocity, s.wind.density, s.wind.drag, s.wind.implicit) if s.wind else Wind(),
        obstacles=[_build_obstacle(o, i, base_dir, allow_large) for i, o in enumerate(s.obstacles)],
        collision=CollisionSettings(**s.collision.model_dump()) if s.collision else CollisionSettings(),
        damping=solver.damping if solver else 0.0,
    )
    options = StepOptions(linear_solver=solver.linear, max_substep_depth=solver.max_substep_depth,
                          pcg_tol=solver.pcg_tol) if solver else StepOptions()
    origin = GridOrigin(tuple(corner_res)) if corner_res is not None else None
    return Scene(name=name, model=model, dt=s.dt, duration=s.duration, frame_time=frame_time, options=options,
                 description=s.description, spec=s.model_dump(mode="json", exclude_unset=True), origin=origin)


def _estimated_obstacle_vertices(o: Any) -> int:
    if o.type == "sphere":
        return 10 * 4 ** o.subdivisions + 2
    if o.type == "plane":
        return (o.divisions + 1) ** 2
    return 8


def _check_limits(s: SceneSpec, name: str, allow_large: bool | None) -> None:
    """Steps, frames, vertices and memory of the run, from the spec alone."""
    steps = max(1, int(round(s.duration / s.dt)))
    per_frame = max(1, int(round(s.effective_frame_time / s.dt)))
    vertices = 0
    if s.cloth.grid is not None:
        nu, nv = s.cloth.grid.resolution
        check_limit(f"scene {name}: cloth.grid.resolution", max(nu, nv), LIMITS.max_grid_resolution,
                    "max_grid_resolution (vertices per side)", allow_large)
        vertices = nu * nv
    obstacle_vertices = sum(_estimated_obstacle_vertices(o) for o in s.obstacles)
    check_run(f"scene {name}", steps, steps // per_frame + 2, vertices, obstacle_vertices, allow_large)


def _build_cloth_mesh(cloth: ClothSpec, base_dir: Path, source: str) -> tuple[ClothMesh, tuple[int, int] | None]:
    if cloth.grid is not None:
        g = cloth.grid
        return grid_mesh(g.resolution, g.size, g.origin, g.orientation), g.resolution
    path = Path(cloth.mesh)
    if not path.is_absolute():
        path = base_dir / path
    if not path.is_file():
        raise SceneError(f"{source}: cloth mesh file {path} does not exist")
    mesh = mesh_from_obj(path)
    if cloth.translate is not None:
        mesh = ClothMesh(mesh.x + torch.tensor(cloth.translate, dtype=mesh.x.dtype), mesh.uv, mesh.faces, mesh.name)
    return mesh, None


def _parse_fabric(spec: Any):
    if hasattr(spec, "model_dump"):
        spec = spec.model_dump(exclude_unset=True)
    try:
        return load_fabric(spec)
    except TryonError:
        raise
    except Exception as exc:  # malformed inline fabric data
        raise SceneError(f"scene: cloth.fabric is not a valid fabric ({type(exc).__name__}: {exc})") from None


def _vertex_list(items: list, mesh: ClothMesh, corner_res, key: str) -> torch.Tensor:
    out = []
    for it in items:
        if isinstance(it, str):
            if corner_res is None:
                raise SceneError(f"scene: '{key}': corner names like {it!r} only work with a grid cloth")
            out.append(grid_corner(corner_res, it))
        else:
            if it >= mesh.num_vertices:
                raise SceneError(f"scene: '{key}': vertex {it} out of range [0, {mesh.num_vertices - 1}]")
            out.append(it)
    return torch.tensor(out, dtype=torch.int64)


def _parse_pins(cloth: ClothSpec, mesh: ClothMesh, corner_res) -> tuple[list[PinGroup], list[SoftHandle]]:
    """Pins and handles held exactly, and soft handles (a handle with a `stiffness`)."""
    groups, soft = [], []
    if cloth.pins:
        groups.append(PinGroup(_vertex_list(cloth.pins, mesh, corner_res, "cloth.pins")))
    for k, h in enumerate(cloth.handles):
        vertices = _vertex_list(h.vertices, mesh, corner_res, f"cloth.handles[{k}].vertices")
        if h.stiffness is None:
            groups.append(PinGroup(vertices, _motion(h.motion)))
        else:
            soft.append(SoftHandle(vertices, float(h.stiffness), _motion(h.motion)))
    return groups, soft


def _motion(spec: MotionSpec | None) -> obs.Motion:
    if spec is None:
        return obs.Motion()
    return obs.Motion(velocity=np.array(spec.velocity), angular_velocity_deg=spec.angular_velocity_deg,
                      axis=np.array(spec.axis), pivot=np.array(spec.pivot), start=spec.start,
                      stop=float("inf") if spec.stop is None else spec.stop)


def _build_obstacle(o: ObstacleSpec, i: int, base_dir: Path, allow_large: bool | None) -> obs.Obstacle:
    name = o.name or f"{o.type}{i}"
    motion = _motion(o.motion)
    if o.type == "sphere":
        return obs.sphere(o.center, o.radius, o.subdivisions, name, motion)
    if o.type == "box":
        return obs.box(o.center, o.size, name, motion)
    if o.type == "plane":
        return obs.plane(o.point, o.normal, o.size, o.divisions, name, motion)
    if o.type == "pyramid":
        return obs.funnel(o.apex, o.rim_size, o.height, name, motion)
    return _mesh_obstacle(o.path, base_dir, name, motion, i, allow_large)


def _mesh_obstacle(path_text: str, base_dir: Path, name: str, motion: obs.Motion, i: int,
                   allow_large: bool | None) -> obs.Obstacle:
    from tryon.limits import check_file_size

    path = Path(path_text)
    path = path if path.is_absolute() else base_dir / path
    if not path.is_file():
        raise SceneError(f"scene: obstacles[{i}] mesh file {path} does not exist")
    check_file_size(path, f"obstacles[{i}] mesh file", allow_large)
    ob = obs.mesh_obstacle(path, name, motion)
    check_limit(f"scene: obstacles[{i}] ({path})", len(ob.rest_vertices), LIMITS.max_obstacle_vertices,
                "max_obstacle_vertices", allow_large)
    if not np.isfinite(ob.rest_vertices).all():
        raise SceneError(f"scene: obstacles[{i}] mesh {path} has NaN or infinite vertex coordinates")
    if len(ob.faces) and (ob.faces.min() < 0 or ob.faces.max() >= len(ob.rest_vertices)):
        raise SceneError(f"scene: obstacles[{i}] mesh {path} has face indices out of range")
    return ob


# ---------------------------------------------------------------------------- examples

def _hanging(res: int) -> dict:
    return {
        "name": "hanging",
        "description": "1 m square pinned at its two top corners, falling and swinging in gravity and a (2, 2, 0) m/s wind",
        "dt": 0.01, "duration": 2.0, "frame_time": 0.04,
        "cloth": {"grid": {"resolution": [res, res], "size": [1.0, 1.0], "origin": [-0.5, -0.5, 1.5]},
                  "fabric": "gray-interlock", "pins": ["top-left", "top-right"]},
        "wind": {"velocity": [2.0, 2.0, 0.0], "density": 1.0, "drag": 0.0},
    }


def _sphere_drop(res: int) -> dict:
    return {
        "name": "sphere-drop",
        "description": "1 m square dropped onto a static sphere of radius 0.25 m",
        "dt": 0.01, "duration": 1.5, "frame_time": 0.04,
        "cloth": {"grid": {"resolution": [res, res], "size": [1.0, 1.0], "origin": [-0.5, -0.5, 0.3]}, "fabric": "gray-interlock"},
        "obstacles": [{"type": "sphere", "center": [0, 0, 0], "radius": 0.25, "subdivisions": 4}],
    }


def _table(res: int) -> dict:
    return {
        "name": "table",
        "description": "a 1 m tablecloth dropped on a 0.6 m square table: friction holds it on the top",
        "dt": 0.01, "duration": 2.0, "frame_time": 0.04,
        "cloth": {"grid": {"resolution": [res, res], "size": [1.0, 1.0], "origin": [-0.5, -0.5, 0.8]}, "fabric": "white-dots-on-blk"},
        "obstacles": [
            {"type": "box", "name": "table", "center": [0, 0, 0.375], "size": [0.6, 0.6, 0.75]},
            {"type": "plane", "name": "floor", "point": [0, 0, 0], "normal": [0, 0, 1], "size": 3.0},
        ],
        "collision": {"friction": 0.6},
    }


def _pyramid(res: int) -> dict:
    return {
        "name": "pyramid",
        "description": "a cloth pushed by a plate into an open upside-down square pyramid: many self and obstacle contacts",
        "dt": 0.01, "duration": 1.2, "frame_time": 0.04,
        "cloth": {"grid": {"resolution": [res, res], "size": [0.8, 0.8], "origin": [-0.4, -0.4, 0.52]}, "fabric": "gray-interlock"},
        "obstacles": [
            {"type": "pyramid", "name": "pyramid", "apex": [0, 0, 0], "rim_size": 0.9, "height": 0.5},
            {"type": "box", "name": "pusher", "center": [0, 0, 0.6], "size": [0.15, 0.15, 0.1],
             "motion": {"velocity": [0, 0, -0.4], "start": 0.0, "stop": 0.8}},
        ],
    }


EXAMPLES = {"hanging": _hanging, "sphere-drop": _sphere_drop, "table": _table, "pyramid": _pyramid}


def example_spec(name: str, resolution: int | None = None) -> dict:
    if name not in EXAMPLES:
        raise SceneError(f"unknown example scene {name!r}; choose one of {sorted(EXAMPLES)}")
    default_res = {"hanging": 32, "sphere-drop": 32, "table": 32, "pyramid": 24}[name]
    return EXAMPLES[name](resolution or default_res)


def example_scene(name: str, resolution: int | None = None, allow_large: bool | None = None, **overrides: Any) -> Scene:
    """A built-in scene; `overrides` replace top-level keys (dt, duration, ...) and
    `fabric` replaces the cloth's fabric."""
    spec = example_spec(name, resolution)
    fabric = overrides.pop("fabric", None)
    if fabric is not None:
        spec["cloth"]["fabric"] = fabric
    spec.update({k: v for k, v in overrides.items() if v is not None})
    return parse_scene(spec, default_name=name, allow_large=allow_large)
