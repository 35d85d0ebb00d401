"""Observed cloth sequences (`tryon fit-fabric` input): reading, writing, and making one
from a fabric preset in the hanging-in-wind scene.

An observed file is an ``.npz`` with

* ``positions [T, N, 3]`` (m): vertex positions per frame, frame 0 the initial state (at
  rest, zero velocity);
* ``faces [F, 3]``, ``uv [N, 2]`` (material coordinates, m);
* ``pinned [k]``: vertices held at their frame-0 positions;
* ``frame_time`` (s), ``gravity [3]`` (m/s^2), ``wind_velocity [3]`` (m/s),
  ``wind_density``, ``wind_drag`` (ARCSim's face drag model, `tryon.sim.forces.wind`);
* optionally ``dt`` (s), the simulation step (default: the largest step <= 0.01 s that
  divides ``frame_time``; `tryon fit-fabric` then chooses its own by a convergence
  check), ``handle_stiffness`` (N/m per axis: the pinned vertices hang from ARCSim's
  soft node handles instead of being held exactly) and ``fabric`` (the name of the fabric
  that made it).

These keys define the hanging-in-wind scene completely (no obstacles, default contact
settings), so ``--scene`` is optional for such files. The scene is integrated as ARCSim
integrates it: the wind force is explicit (no velocity Jacobian in the solve) and soft
handles are implicit penalty springs to the handles' start positions.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from tryon.errors import InputFileError, TryonError
from tryon.fabric.base import Fabric
from tryon.fabric.presets import load_fabric
from tryon.io.atomic import atomic_write
from tryon.limits import LIMITS, check_limit
from tryon.sim.integrator import ImplicitEulerSolver
from tryon.sim.loop import FrameRecorder, run
from tryon.sim.mesh import ClothMesh
from tryon.sim.model import ClothModel, PinGroup, SoftHandle, Wind
from tryon.sim.scene import example_spec, parse_scene

REQUIRED_KEYS = ("positions", "faces", "uv", "pinned", "frame_time", "gravity", "wind_velocity", "wind_density", "wind_drag")
MAX_DT = 0.01


@dataclass
class Observation:
    """An observed sequence and the scene it was recorded in (module docstring)."""

    positions: np.ndarray
    faces: np.ndarray
    uv: np.ndarray
    pinned: np.ndarray
    frame_time: float
    gravity: np.ndarray
    wind_velocity: np.ndarray
    wind_density: float
    wind_drag: float
    dt: float
    fabric: str = ""
    handle_stiffness: float = 0.0  # N/m per axis; 0: the pinned vertices are held exactly
    dt_given: bool = True  # False: dt is `default_dt`, the file did not set it

    @property
    def num_frames(self) -> int:
        return int(self.positions.shape[0])

    @property
    def steps_per_frame(self) -> int:
        return max(1, int(round(self.frame_time / self.dt)))

    def cloth_size(self) -> float:
        """Diagonal of the material-space bounding box (m), the scale of simulation errors."""
        return float(np.linalg.norm(self.uv.max(0) - self.uv.min(0)))

    def model(self, fabric: Fabric) -> ClothModel:
        """The hanging-in-wind `ClothModel` of this observation with `fabric`."""
        mesh = ClothMesh(torch.from_numpy(self.positions[0].copy()), torch.from_numpy(self.uv), torch.from_numpy(self.faces),
                         name="observed")
        pinned = torch.from_numpy(self.pinned)
        soft = self.handle_stiffness > 0
        pins = [PinGroup(pinned)] if len(self.pinned) and not soft else []
        handles = [SoftHandle(pinned, float(self.handle_stiffness))] if len(self.pinned) and soft else []
        wind = Wind(tuple(float(v) for v in self.wind_velocity), float(self.wind_density), float(self.wind_drag),
                    implicit=False)
        return ClothModel(mesh, fabric, pins=pins, handles=handles, gravity=tuple(float(g) for g in self.gravity),
                          wind=wind)


def default_dt(frame_time: float) -> float:
    """The largest step <= `MAX_DT` that divides the frame time."""
    return frame_time / max(1, math.ceil(frame_time / MAX_DT - 1e-9))


MIN_FRAME_TIME, MAX_FRAME_TIME = 1e-3, 10.0  # s
MIN_DT = 1e-5  # s
MAX_HANDLE_STIFFNESS = 1e9  # N/m


def load_observed(path: str | Path, allow_large: bool | None = None) -> Observation:
    """Read and check an observed ``.npz`` (module docstring); raises `InputFileError`
    naming the file and key, or `LimitError` for sequences beyond `tryon.limits`."""
    from tryon.io import npz

    source = f"observed file {path}"
    data = npz.read_npz(path, "observed file", allow_large)
    missing = [k for k in REQUIRED_KEYS if k not in data]
    if missing:
        raise InputFileError(f"{source}: missing keys {missing}; required: {list(REQUIRED_KEYS)} "
                             f"(make one with `tryon fit-fabric --make-observed PRESET OUT.npz`)")
    pos = npz.float_array(data, "positions", source, (None, None, 3))
    T, n = pos.shape[0], pos.shape[1]
    if T < 2 or n < 3:
        raise InputFileError(f"{source}: 'positions' needs at least 2 frames of 3 vertices, got shape {list(pos.shape)}")
    check_limit(f"{source}: frames", T, LIMITS.max_frames, "max_frames", allow_large)
    check_limit(f"{source}: vertices", n, LIMITS.max_vertices, "max_vertices", allow_large)
    faces = npz.int_array(data, "faces", source, (None, 3), below=n)
    if len(faces) == 0:
        raise InputFileError(f"{source}: 'faces' is empty; the cloth needs triangles")
    uv = npz.float_array(data, "uv", source, (n, 2))
    pinned = npz.int_array(data, "pinned", source, None, below=n).reshape(-1)
    frame_time = npz.scalar(data, "frame_time", source, MIN_FRAME_TIME, MAX_FRAME_TIME, "s")
    dt_given = "dt" in data
    dt = npz.scalar(data, "dt", source, MIN_DT, frame_time, "s") if dt_given else default_dt(frame_time)
    handle_k = npz.scalar(data, "handle_stiffness", source, 0.0, MAX_HANDLE_STIFFNESS, "N/m") \
        if "handle_stiffness" in data else 0.0
    steps = (T - 1) * max(1, int(round(frame_time / dt)))
    check_limit(f"{source}: simulation steps per run ((frames - 1) * frame_time / dt)", steps, LIMITS.max_steps,
                "max_steps", allow_large)
    gravity, wind = _vector(data, "gravity", source, 1000.0), _vector(data, "wind_velocity", source, 1000.0)
    return Observation(pos, faces, uv, pinned, frame_time, gravity, wind,
                       npz.scalar(data, "wind_density", source, 0.0, 100.0, "kg/m^3"),
                       npz.scalar(data, "wind_drag", source, 0.0, 100.0), dt, npz.text(data, "fabric", source, "", 200),
                       handle_k, dt_given)


def _vector(data: dict, key: str, source: str, bound: float) -> np.ndarray:
    from tryon.io import npz

    value = npz.float_array(data, key, source, (3,))
    if np.abs(value).max() > bound:
        raise InputFileError(f"{source}: {key!r} components must lie within +-{bound:g}, got {value.tolist()}")
    return value


def camera_only(obs: Observation) -> Observation:
    """`obs` with only what a camera gives: no simulator step, handle stiffness or fabric
    name (the step falls back to `default_dt`, as when a file has none)."""
    return Observation(obs.positions, obs.faces, obs.uv, obs.pinned, obs.frame_time, obs.gravity, obs.wind_velocity,
                       obs.wind_density, obs.wind_drag, default_dt(obs.frame_time), "", 0.0, dt_given=False)


def save_observed(path: str | Path, obs: Observation) -> None:
    """Write `obs` as an observed ``.npz`` (atomic)."""
    with atomic_write(path, "wb") as fh:
        np.savez(fh, positions=obs.positions, faces=obs.faces, uv=obs.uv, pinned=obs.pinned, frame_time=obs.frame_time,
                 gravity=obs.gravity, wind_velocity=obs.wind_velocity, wind_density=obs.wind_density,
                 wind_drag=obs.wind_drag, **({"fabric": obs.fabric} if obs.fabric else {}),
                 **({"dt": obs.dt} if obs.dt_given else {}),
                 **({"handle_stiffness": obs.handle_stiffness} if obs.handle_stiffness > 0 else {}))


def simulate_frames(model: ClothModel, frames: int, steps_per_frame: int, dt: float, progress: bool = False,
                    fabric: Fabric | None = None) -> np.ndarray:
    """Positions ``[frames, N, 3]`` of a forward run from the model's initial state at rest
    (with `fabric` instead of the model's when given)."""
    state = model.initial_state()
    frames_kept = FrameRecorder(steps_per_frame, (frames - 1) * steps_per_frame, first=state)
    run(ImplicitEulerSolver(model, fabric=fabric), state, dt, until=(frames - 1) * steps_per_frame, observers=[frames_kept],
        progress="simulating" if progress else None)
    return np.stack(frames_kept.positions)


def make_observed(fabric: str | Fabric, resolution: int = 10, duration: float = 1.0, frame_time: float = 0.04,
                  dt: float = 0.01, progress: bool = False) -> Observation:
    """A hanging-in-wind sequence made with `fabric` (a preset name, file or `Fabric`):
    the `hanging` example (1 m square pinned at two corners, (2, 2, 0) m/s wind)."""
    fab = load_fabric(fabric) if not isinstance(fabric, Fabric) else fabric
    if resolution < 2 or duration <= 0 or frame_time <= 0 or not 0 < dt <= frame_time:
        raise TryonError("make_observed: need resolution >= 2 and 0 < dt <= frame_time, duration > 0")
    spec = example_spec("hanging", resolution)
    scene = parse_scene(spec)
    wind = scene.model.wind
    base = Observation(scene.model.mesh.x.numpy()[None].copy(), scene.model.faces.numpy(),
                       scene.model.mesh.uv.numpy(), scene.model.pinned.numpy(), frame_time,
                       scene.model.gravity.numpy(), np.asarray(wind.velocity, float), wind.density, wind.drag, dt,
                       getattr(fab, "name", ""))
    frames = int(round(duration / frame_time)) + 1
    base.positions = simulate_frames(base.model(fab), frames, base.steps_per_frame, dt, progress)
    return base
