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
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from tryon.errors import InputFileError
from tryon.io.atomic import atomic_write, check_output_dir, claim_work_dir, publish_dir
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
    """Simulate `scene` for its duration, keeping every `frame_time` a frame. With a
    `checkpoint_dir`, a checkpoint every `checkpoint_every` frames holds everything the
    next step depends on, so a run resumed from it (`resume=True`) ends exactly where the
    uninterrupted run ends, and its summary counts the whole run."""
    model = scene.model
    solver = ImplicitEulerSolver(model, scene.options)
    run = _RunProgress(frames=[model.initial_state().x.numpy().copy()], times=[0.0])
    state = model.initial_state()
    if resume and checkpoint_dir is not None:
        loaded = _load_checkpoint(checkpoint_dir / CHECKPOINT, scene, solver)
        if loaded is not None:
            state, run = loaded
    n_steps, per_frame = scene.num_steps, scene.steps_per_frame
    wall0 = time.perf_counter() - run.wall_s
    bar = tqdm(total=n_steps, initial=run.step, desc=f"simulate {scene.name}", unit="step", disable=not progress,
               leave=False)
    for k in range(run.step, n_steps):
        state, st = solver.step(state, scene.dt)
        run.totals.merge(st)
        run.retried_steps += int(st.retried)
        bar.update(1)
        if (k + 1) % per_frame == 0 or k + 1 == n_steps:
            run.frames.append(state.x.numpy().copy())
            run.times.append(state.t)
            if checkpoint_dir is not None and len(run.frames) % checkpoint_every == 0:
                run.step, run.wall_s = k + 1, time.perf_counter() - wall0
                _save_checkpoint(checkpoint_dir / CHECKPOINT, scene, state, run, solver)
    bar.close()
    wall = time.perf_counter() - wall0
    positions = np.stack(run.frames)
    frame_metrics = [state_metrics(model, x, t) for x, t in zip(positions, run.times)]
    summary = _summary(scene, n_steps, wall, run.totals, run.retried_steps, frame_metrics)
    summary["resumed_at_step"] = run.resumed_at
    if run.retried_steps and progress:
        print(f"note: {run.retried_steps} step(s) needed substeps (collision response or NaN); see summary.json")
    return RunResult(positions, np.asarray(run.times), summary, frame_metrics)


@dataclass
class _RunProgress:
    """What a run has done so far (restored from a checkpoint on resume)."""

    frames: list
    times: list
    step: int = 0
    wall_s: float = 0.0
    retried_steps: int = 0
    resumed_at: int | None = None
    totals: StepStats = field(default_factory=StepStats)


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


_TOTAL_FIELDS = ("substeps", "contacts", "impacts", "collision_iterations", "solver_iterations", "retried", "fallback")


def _save_checkpoint(path: Path, scene: Scene, state: ClothState, run: _RunProgress, solver: ImplicitEulerSolver) -> None:
    totals = {k: getattr(run.totals, k) for k in _TOTAL_FIELDS} | {"seconds": run.totals.seconds}
    progress = {"step": run.step, "wall_s": run.wall_s, "retried_steps": run.retried_steps, "totals": totals}
    tmp = path.with_suffix(".tmp.npz")
    np.savez(tmp, x=state.x.numpy(), v=state.v.numpy(), t=state.t, frames=np.stack(run.frames),
             times=np.asarray(run.times), fingerprint=scene_fingerprint(scene), progress=json.dumps(progress),
             **{f"solver_{k}": v for k, v in solver.checkpoint_arrays().items()})
    os.replace(tmp, path)


def _load_checkpoint(path: Path, scene: Scene, solver: ImplicitEulerSolver) -> tuple[ClothState, _RunProgress] | None:
    if not path.exists():
        return None
    try:
        with np.load(path, allow_pickle=False) as data:
            arrays = {k: data[k] for k in data.files}
        fingerprint = str(arrays["fingerprint"])
        progress = json.loads(str(arrays["progress"]))
        x, v, frames = arrays["x"], arrays["v"], arrays["frames"]
        n = scene.model.num_vertices
        if x.shape != (n, 3) or v.shape != (n, 3) or frames.ndim != 3 or frames.shape[1:] != (n, 3):
            raise ValueError("array shapes do not match the scene's cloth")
    except (OSError, KeyError, ValueError, TypeError) as exc:
        raise InputFileError(f"checkpoint {path} cannot be read ({exc}); run again without --resume") from exc
    if fingerprint != scene_fingerprint(scene):
        raise InputFileError(f"checkpoint {path} belongs to a different scene (its settings changed since); run "
                             "again without --resume to start over")
    solver.restore_arrays({k[len("solver_"):]: a for k, a in arrays.items() if k.startswith("solver_")})
    totals = progress["totals"]
    run = _RunProgress(frames=list(frames), times=[float(t) for t in arrays["times"]], step=int(progress["step"]),
                       wall_s=float(progress["wall_s"]), retried_steps=int(progress["retried_steps"]),
                       resumed_at=int(progress["step"]),
                       totals=StepStats(**{k: totals[k] for k in _TOTAL_FIELDS}, seconds=dict(totals["seconds"])))
    state = ClothState(torch.from_numpy(x), torch.from_numpy(v), float(arrays["t"]))
    return state, run


def run_scene(scene: Scene, out_dir: str | Path, progress: bool = True, resume: bool = False, write_objs: bool = True,
              force: bool = False) -> RunResult:
    """Simulate and write frames, OBJs, summary.json and a picture into out_dir. The folder
    is assembled in `<out_dir>.partial` (which keeps the checkpoint until the run ends) and
    renamed into place; an existing out_dir is replaced only when tryon wrote it (or with
    `force`, see `tryon.io.atomic.check_output_dir`)."""
    from tryon.io.frames import save_frames_npz, write_obj_sequence

    out_dir = check_output_dir(out_dir, force=force)
    work = claim_work_dir(out_dir.with_name(out_dir.name + ".partial"), resume=resume, force=force)
    result = simulate(scene, progress=progress, checkpoint_dir=work, resume=resume)
    m = scene.model
    faces, uv = m.faces.numpy(), m.mesh.uv.numpy()
    save_frames_npz(work / "frames.npz", result.positions, faces, uv=uv, times=result.times)
    if write_objs:
        write_obj_sequence(work / "obj", result.positions, faces, uv=uv)
    render_state_png(scene, result.positions[-1], float(result.times[-1]), work / "last_frame.png")
    with atomic_write(work / "summary.json") as fh:
        json.dump(result.summary, fh, indent=2)
    (work / CHECKPOINT).unlink(missing_ok=True)
    publish_dir(work, out_dir, force=force)
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
