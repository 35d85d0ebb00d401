"""Run a scene to the end: step, record frames, measure, checkpoint, write outputs.

Outputs of `run_scene(scene, out_dir)`:
  frames.npz (positions [T,N,3], faces, uv, times), obj/frame_0000.obj ..., summary.json,
  last_frame.png. The directory is assembled under `<out>.partial` and renamed when
  complete; a checkpoint there lets an interrupted run resume (`resume=True`).
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from tryon.sim.integrator import ImplicitEulerSolver, StepStats
from tryon.sim.metrics import state_metrics
from tryon.sim.model import ClothState
from tryon.sim.scene import Scene

CHECKPOINT = "checkpoint.npz"


@dataclass
class RunResult:
    positions: np.ndarray  # [T,N,3]
    times: np.ndarray  # [T]
    summary: dict
    frame_metrics: list[dict] = field(default_factory=list)


def scene_fingerprint(scene: Scene) -> str:
    return hashlib.sha1(json.dumps(scene.spec, sort_keys=True, default=str).encode()).hexdigest()[:16]


def simulate(scene: Scene, progress: bool = True, checkpoint_dir: Path | None = None, resume: bool = False,
             checkpoint_every: int = 10) -> RunResult:
    """Simulate `scene` for its duration, keeping every `frame_time` a frame."""
    model = scene.model
    solver = ImplicitEulerSolver(model, scene.options)
    state = model.initial_state()
    frames, times = [state.x.numpy().copy()], [0.0]
    step0 = 0
    totals = StepStats()
    if resume and checkpoint_dir is not None:
        loaded = _load_checkpoint(checkpoint_dir / CHECKPOINT, scene)
        if loaded is not None:
            state, frames, times, step0 = loaded
    n_steps, per_frame = scene.num_steps, scene.steps_per_frame
    wall0 = time.perf_counter()
    bar = tqdm(total=n_steps, initial=step0, desc=f"simulate {scene.name}", unit="step", disable=not progress, leave=False)
    retried_steps = 0
    for k in range(step0, n_steps):
        state, st = solver.step(state, scene.dt)
        totals.merge(st)
        retried_steps += int(st.retried)
        bar.update(1)
        if (k + 1) % per_frame == 0 or k + 1 == n_steps:
            frames.append(state.x.numpy().copy())
            times.append(state.t)
            if checkpoint_dir is not None and len(frames) % checkpoint_every == 0:
                _save_checkpoint(checkpoint_dir / CHECKPOINT, scene, state, frames, times, k + 1)
    bar.close()
    wall = time.perf_counter() - wall0
    positions = np.stack(frames)
    frame_metrics = [state_metrics(model, x, t) for x, t in zip(positions, times)]
    summary = _summary(scene, n_steps - step0, wall, totals, retried_steps, frame_metrics)
    if retried_steps and progress:
        print(f"note: {retried_steps} step(s) needed substeps (collision response or NaN); see summary.json")
    return RunResult(positions, np.asarray(times), summary, frame_metrics)


def _summary(scene: Scene, steps: int, wall: float, totals: StepStats, retried: int, fm: list[dict]) -> dict:
    m = scene.model
    return {
        "scene": scene.name,
        "vertices": m.num_vertices,
        "faces": int(m.faces.shape[0]),
        "fabric": m.fabric.name,
        "dt": scene.dt,
        "duration": scene.duration,
        "steps": steps,
        "frames": len(fm),
        "wall_s": wall,
        "s_per_step": wall / max(steps, 1),
        "seconds": {k: v for k, v in totals.seconds.items()},
        "substeps": totals.substeps,
        "retried_steps": retried,
        "fail_safe_used": bool(totals.fallback),
        "max_strain": max(f["max_strain"] for f in fm),
        "final_max_strain": fm[-1]["max_strain"],
        "min_obstacle_distance": min(f["min_obstacle_distance"] for f in fm),
        "intersections": max(f["self_intersections"] + f["obstacle_intersections"] for f in fm),
        "final_intersections": fm[-1]["self_intersections"] + fm[-1]["obstacle_intersections"],
        "contacts_total": totals.contacts,
        "impacts_total": totals.impacts,
        "finite": True,
    }


def _save_checkpoint(path: Path, scene: Scene, state: ClothState, frames, times, step: int) -> None:
    tmp = path.with_suffix(".tmp.npz")
    np.savez(tmp, x=state.x.numpy(), v=state.v.numpy(), t=state.t, frames=np.stack(frames), times=np.asarray(times),
             step=step, fingerprint=scene_fingerprint(scene))
    os.replace(tmp, path)


def _load_checkpoint(path: Path, scene: Scene):
    if not path.exists():
        return None
    data = np.load(path)
    if str(data["fingerprint"]) != scene_fingerprint(scene):
        return None
    state = ClothState(torch.from_numpy(data["x"]), torch.from_numpy(data["v"]), float(data["t"]))
    return state, list(data["frames"]), list(data["times"]), int(data["step"])


def run_scene(scene: Scene, out_dir: str | Path, progress: bool = True, resume: bool = False, write_objs: bool = True) -> RunResult:
    """Simulate and write frames, OBJs, summary.json and a picture into out_dir."""
    from tryon.io.frames import save_frames_npz, write_obj_sequence

    out_dir = Path(out_dir)
    work = out_dir.with_name(out_dir.name + ".partial")
    if work.exists() and not resume:
        shutil.rmtree(work)
    work.mkdir(parents=True, exist_ok=True)
    result = simulate(scene, progress=progress, checkpoint_dir=work, resume=resume)
    m = scene.model
    faces, uv = m.faces.numpy(), m.mesh.uv.numpy()
    save_frames_npz(work / "frames.npz", result.positions, faces, uv=uv, times=result.times)
    if write_objs:
        write_obj_sequence(work / "obj", result.positions, faces, uv=uv)
    render_state_png(scene, result.positions[-1], float(result.times[-1]), work / "last_frame.png")
    (work / "summary.json").write_text(json.dumps(result.summary, indent=2))
    (work / CHECKPOINT).unlink(missing_ok=True)
    if out_dir.exists():
        shutil.rmtree(out_dir)
    os.replace(work, out_dir)
    return result


def render_state_png(scene: Scene, x: np.ndarray, t: float, path: Path, width: int = 800, height: int = 800) -> None:
    """Picture of the cloth (coloured by strain) and the obstacles at time t."""
    from tryon.render.colormap import add_colorbar, scalar_to_rgb
    from tryon.render.offscreen import Camera, RenderMesh, render_meshes, save_png
    from tryon.sim.metrics import face_strain

    m = scene.model
    strain = face_strain(m, torch.from_numpy(np.ascontiguousarray(x))).numpy() * 100.0
    vmax = max(5.0, float(np.percentile(strain, 99)))
    meshes = [RenderMesh(x, m.faces.numpy(), face_colors=scalar_to_rgb(strain, 0.0, vmax, "viridis"))]
    ob = m.obstacles.vertices_at(t)
    for name, verts, faces in m.obstacles.per_obstacle(ob):
        meshes.append(RenderMesh(verts, faces, color=(0.75, 0.72, 0.68), smooth=name.startswith("sphere")))
    cloth_only = [meshes[0]]
    cam = Camera.fit(cloth_only if scene.name == "hanging" else meshes[:1] + meshes[1:2], view="three_quarter", margin=1.3)
    image = render_meshes(meshes, width, height, camera=cam)
    image = add_colorbar(image, 0.0, vmax, "viridis", "strain %")
    save_png(path, image)
