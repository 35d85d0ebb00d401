"""Declarative scenes: a YAML file (or a built-in example) describing a cloth, its fabric,
pins and handles, wind, obstacles with motion, time step and duration.

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

import copy
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
import yaml

from tryon.errors import SceneError, TryonError
from tryon.fabric import load_fabric
from tryon.sim import obstacles as obs
from tryon.sim.integrator import StepOptions
from tryon.sim.mesh import ClothMesh, grid_corner, grid_mesh, mesh_from_obj
from tryon.sim.model import ClothModel, CollisionSettings, PinGroup, Wind
from tryon.sim.origin import ClothOrigin

TOP_KEYS = {"name", "description", "dt", "duration", "frame_time", "gravity", "cloth", "wind", "obstacles", "collision", "solver"}


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


def load_scene(path: str | Path) -> Scene:
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as exc:
        raise SceneError(f"scene file {path}: cannot be read ({exc.strerror})") from exc
    try:
        spec = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise SceneError(f"scene file {path}: malformed YAML ({str(exc).splitlines()[0]})") from exc
    if not isinstance(spec, dict):
        raise SceneError(f"scene file {path}: the top level must be a mapping with at least a 'cloth' key")
    return parse_scene(spec, base_dir=path.parent, default_name=path.stem)


def parse_scene(spec: dict, base_dir: Path | None = None, default_name: str = "scene") -> Scene:
    spec = copy.deepcopy(spec)
    unknown = set(spec) - TOP_KEYS
    if unknown:
        raise SceneError(f"scene: unknown key(s) {sorted(unknown)}; allowed: {sorted(TOP_KEYS)}")
    if "cloth" not in spec:
        raise SceneError("scene: missing the 'cloth' section (a grid or a mesh plus a fabric)")
    base_dir = base_dir or Path(".")
    dt = _positive(spec.get("dt", 0.01), "dt")
    duration = _positive(spec.get("duration", 1.0), "duration")
    frame_time = _positive(spec.get("frame_time", max(dt, 0.04)), "frame_time")
    if frame_time < dt:
        raise SceneError(f"scene: frame_time ({frame_time}) must be at least dt ({dt})")
    mesh, corner_res = _parse_cloth_mesh(spec["cloth"], base_dir)
    fabric = _parse_fabric(spec["cloth"].get("fabric", "gray-interlock"))
    pins = _parse_pins(spec["cloth"], mesh, corner_res)
    model = ClothModel(
        mesh,
        fabric,
        pins=pins,
        gravity=tuple(_vec(spec.get("gravity", [0.0, 0.0, -9.8]), "gravity")),
        wind=_parse_wind(spec.get("wind")),
        obstacles=[_parse_obstacle(o, i, base_dir) for i, o in enumerate(spec.get("obstacles") or [])],
        collision=_parse_collision(spec.get("collision")),
        damping=float((spec.get("solver") or {}).get("damping", 0.0)),
    )
    solver = spec.get("solver") or {}
    options = StepOptions(
        linear_solver=str(solver.get("linear", "auto")),
        max_substep_depth=int(solver.get("max_substep_depth", 3)),
        pcg_tol=float(solver.get("pcg_tol", 1e-4)),
    )
    return Scene(
        name=str(spec.get("name", default_name)), model=model, dt=dt, duration=duration, frame_time=frame_time,
        options=options, description=str(spec.get("description", "")), spec=spec,
    )


def _positive(value: Any, key: str) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError) as exc:
        raise SceneError(f"scene: '{key}' must be a number, got {value!r}") from exc
    if not np.isfinite(v) or v <= 0:
        raise SceneError(f"scene: '{key}' must be a positive number, got {value!r}")
    return v


def _vec(value: Any, key: str, n: int = 3) -> list[float]:
    try:
        out = [float(a) for a in value]
    except (TypeError, ValueError) as exc:
        raise SceneError(f"scene: '{key}' must be a list of {n} numbers, got {value!r}") from exc
    if len(out) != n or not all(np.isfinite(out)):
        raise SceneError(f"scene: '{key}' must be a list of {n} finite numbers, got {value!r}")
    return out


def _parse_cloth_mesh(cloth: dict, base_dir: Path) -> tuple[ClothMesh, tuple[int, int] | None]:
    if not isinstance(cloth, dict):
        raise SceneError("scene: 'cloth' must be a mapping with 'grid' or 'mesh'")
    if "grid" in cloth:
        g = cloth["grid"] or {}
        res = g.get("resolution", [32, 32])
        if isinstance(res, int):
            res = [res, res]
        res = (int(res[0]), int(res[1]))
        size = _vec(g.get("size", [1.0, 1.0]), "cloth.grid.size", 2)
        origin = _vec(g.get("origin", [0.0, 0.0, 0.0]), "cloth.grid.origin")
        return grid_mesh(res, tuple(size), tuple(origin), str(g.get("orientation", "horizontal"))), res
    if "mesh" in cloth:
        path = Path(cloth["mesh"])
        if not path.is_absolute():
            path = base_dir / path
        if not path.exists():
            raise SceneError(f"scene: cloth mesh file {path} does not exist")
        mesh = mesh_from_obj(path)
        tr = cloth.get("translate")
        if tr is not None:
            mesh = ClothMesh(mesh.x + torch.tensor(_vec(tr, "cloth.translate"), dtype=mesh.x.dtype), mesh.uv, mesh.faces, mesh.name)
        return mesh, None
    raise SceneError("scene: 'cloth' needs either 'grid' or 'mesh'")


def _parse_fabric(spec: Any):
    try:
        return load_fabric(spec)
    except TryonError:
        raise
    except Exception as exc:  # malformed dicts
        raise SceneError(f"scene: cloth.fabric {spec!r} is not a valid fabric ({exc})") from exc


def _vertex_list(items: Any, mesh: ClothMesh, corner_res, key: str) -> torch.Tensor:
    if not isinstance(items, (list, tuple)):
        raise SceneError(f"scene: '{key}' must be a list of vertex indices or grid corner names")
    out = []
    for it in items:
        if isinstance(it, str):
            if corner_res is None:
                raise SceneError(f"scene: '{key}': corner names like {it!r} only work with a grid cloth")
            try:
                out.append(grid_corner(corner_res, it))
            except TryonError as exc:
                raise SceneError(f"scene: '{key}': {exc}") from exc
        else:
            i = int(it)
            if i < 0 or i >= mesh.num_vertices:
                raise SceneError(f"scene: '{key}': vertex {i} out of range [0, {mesh.num_vertices - 1}]")
            out.append(i)
    return torch.tensor(out, dtype=torch.int64)


def _parse_pins(cloth: dict, mesh: ClothMesh, corner_res) -> list[PinGroup]:
    groups = []
    if cloth.get("pins"):
        groups.append(PinGroup(_vertex_list(cloth["pins"], mesh, corner_res, "cloth.pins")))
    for k, h in enumerate(cloth.get("handles") or []):
        if not isinstance(h, dict) or "vertices" not in h:
            raise SceneError(f"scene: cloth.handles[{k}] needs 'vertices' and optionally 'motion'")
        groups.append(PinGroup(_vertex_list(h["vertices"], mesh, corner_res, f"cloth.handles[{k}].vertices"), _parse_motion(h.get("motion"), f"cloth.handles[{k}]")))
    return groups


def _parse_motion(spec: Any, key: str) -> obs.Motion:
    if spec is None:
        return obs.Motion()
    if not isinstance(spec, dict):
        raise SceneError(f"scene: {key}.motion must be a mapping")
    allowed = {"velocity", "angular_velocity_deg", "axis", "pivot", "start", "stop"}
    unknown = set(spec) - allowed
    if unknown:
        raise SceneError(f"scene: {key}.motion: unknown key(s) {sorted(unknown)}; allowed: {sorted(allowed)}")
    return obs.Motion(
        velocity=np.array(_vec(spec.get("velocity", [0, 0, 0]), f"{key}.motion.velocity")),
        angular_velocity_deg=float(spec.get("angular_velocity_deg", 0.0)),
        axis=np.array(_vec(spec.get("axis", [0, 0, 1]), f"{key}.motion.axis")),
        pivot=np.array(_vec(spec.get("pivot", [0, 0, 0]), f"{key}.motion.pivot")),
        start=float(spec.get("start", 0.0)),
        stop=float(spec.get("stop", float("inf"))),
    )


def _parse_obstacle(spec: Any, i: int, base_dir: Path) -> obs.Obstacle:
    key = f"obstacles[{i}]"
    if not isinstance(spec, dict) or "type" not in spec:
        raise SceneError(f"scene: {key} must be a mapping with a 'type' (sphere, box, plane, pyramid, mesh)")
    kind = spec["type"]
    name = str(spec.get("name", f"{kind}{i}"))
    motion = _parse_motion(spec.get("motion"), key)
    try:
        if kind == "sphere":
            return obs.sphere(_vec(spec.get("center", [0, 0, 0]), f"{key}.center"), float(spec["radius"]), int(spec.get("subdivisions", 3)), name, motion)
        if kind == "box":
            return obs.box(_vec(spec.get("center", [0, 0, 0]), f"{key}.center"), _vec(spec["size"], f"{key}.size"), name, motion)
        if kind == "plane":
            return obs.plane(_vec(spec.get("point", [0, 0, 0]), f"{key}.point"), _vec(spec.get("normal", [0, 0, 1]), f"{key}.normal"), float(spec.get("size", 4.0)), int(spec.get("divisions", 8)), name, motion)
        if kind == "pyramid":
            return obs.funnel(_vec(spec.get("apex", [0, 0, 0]), f"{key}.apex"), float(spec["rim_size"]), float(spec["height"]), name, motion)
        if kind == "mesh":
            path = Path(spec["path"])
            return obs.mesh_obstacle(path if path.is_absolute() else base_dir / path, name, motion)
    except KeyError as exc:
        raise SceneError(f"scene: {key} ({kind}) is missing the key {exc.args[0]!r}") from exc
    raise SceneError(f"scene: {key} has unknown type {kind!r}; use sphere, box, plane, pyramid or mesh")


def _parse_wind(spec: Any) -> Wind:
    if spec is None:
        return Wind()
    if not isinstance(spec, dict):
        raise SceneError("scene: 'wind' must be a mapping {velocity, density, drag}")
    return Wind(tuple(_vec(spec.get("velocity", [0, 0, 0]), "wind.velocity")), float(spec.get("density", 1.0)), float(spec.get("drag", 0.0)))


def _parse_collision(spec: Any) -> CollisionSettings:
    if spec is None:
        return CollisionSettings()
    if not isinstance(spec, dict):
        raise SceneError("scene: 'collision' must be a mapping")
    allowed = set(CollisionSettings.__dataclass_fields__)
    unknown = set(spec) - allowed
    if unknown:
        raise SceneError(f"scene: collision: unknown key(s) {sorted(unknown)}; allowed: {sorted(allowed)}")
    cs = CollisionSettings(**spec)
    if cs.thickness <= 0:
        raise SceneError(f"scene: collision.thickness must be positive, got {cs.thickness}")
    return cs


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


def example_scene(name: str, resolution: int | None = None, **overrides: Any) -> Scene:
    """A built-in scene; `overrides` replace top-level keys (dt, duration, ...) and
    `fabric` replaces the cloth's fabric."""
    spec = example_spec(name, resolution)
    fabric = overrides.pop("fabric", None)
    if fabric is not None:
        spec["cloth"]["fabric"] = fabric
    spec.update({k: v for k, v in overrides.items() if v is not None})
    return parse_scene(spec, default_name=name)
