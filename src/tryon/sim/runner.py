"""Run a scene to the end: step, record frames, measure, checkpoint, write outputs.

Outputs of `run_scene(scene, out_dir, picture=...)`:
  frames.npz (positions [T,N,3], faces, uv, times), obj/frame_0000.obj ..., summary.json,
  and last_frame.png when a `picture` function is given (`tryon simulate` passes
  `tryon.render.sim_pictures.render_state_png`). The directory is assembled under
  `<out>.partial` and renamed when complete; a checkpoint there lets an interrupted run
  resume exactly (`resume=True`).
"""

from __future__ import annotations

import dataclasses
import hashlib
from collections.abc import Callable
import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from tryon.errors import InputFileError
from tryon.io.npz import float_array, read_npz
from tryon.io.atomic import atomic_write, check_output_dir, claim_work_dir, publish_dir
from tryon.sim.integrator import ImplicitEulerSolver, StepStats
from tryon.sim.loop import FrameRecorder, RunOutcome, StepRecord, run
from tryon.sim.metrics import state_metrics
from tryon.sim.model import ClothState
from tryon.sim.scene import Scene
from tryon.io.json_safe import dumps_json

CHECKPOINT = "checkpoint.npz"


@dataclass
class RunResult:
    positions: np.ndarray  # [T,N,3]
    times: np.ndarray  # [T]
    summary: dict
    frame_metrics: list[dict] = field(default_factory=list)


def scene_fingerprint(scene: Scene) -> str:
    """What a checkpoint must agree with to be resumed: the scene, the solver options and
    the software version."""
    from tryon import __version__

    key = {"spec": scene.spec, "options": dataclasses.asdict(scene.options), "version": __version__}
    return hashlib.sha1(json.dumps(key, sort_keys=True, default=str).encode()).hexdigest()[:16]


def simulate(scene: Scene, progress: bool = True, checkpoint_dir: Path | None = None, resume: bool = False,
             checkpoint_every: int = 10) -> RunResult:
    """Simulate `scene` for its duration, keeping every `frame_time` a frame. With a
    `checkpoint_dir`, a checkpoint every `checkpoint_every` frames holds everything the
    next step depends on, so a run resumed from it (`resume=True`) ends exactly where the
    uninterrupted run ends, and its summary counts the whole run."""
    model = scene.model
    solver = ImplicitEulerSolver(model, scene.options)
    n_steps = scene.num_steps
    state = model.initial_state()
    frames = FrameRecorder(scene.steps_per_frame, n_steps, first=state)
    outcome, resumed_at = RunOutcome(state, 0), None
    if resume and checkpoint_dir is not None:
        loaded = _load_checkpoint(checkpoint_dir / CHECKPOINT, scene, solver)
        if loaded is not None:
            outcome, frames.positions, frames.times = loaded
            resumed_at = outcome.step
    observers: list = [frames]
    if checkpoint_dir is not None:
        def checkpoint(rec: StepRecord) -> None:
            if frames.times[-1] == rec.state.t and len(frames.times) % checkpoint_every == 0:
                _save_checkpoint(checkpoint_dir / CHECKPOINT, scene, outcome, frames, solver)

        observers.append(checkpoint)
    outcome = run(solver, outcome.state, scene.dt, until=n_steps, start=outcome.step, observers=observers,
                  progress=f"simulate {scene.name}" if progress else None, outcome=outcome)
    positions = np.stack(frames.positions)
    frame_metrics = [state_metrics(model, x, t) for x, t in zip(positions, frames.times)]
    summary = _summary(scene, n_steps, outcome.wall_s, outcome.totals, outcome.retried_steps, frame_metrics)
    summary["resumed_at_step"] = resumed_at
    if outcome.retried_steps and progress:
        print(f"note: {outcome.retried_steps} step(s) needed substeps (collision response or NaN); see summary.json")
    return RunResult(positions, np.asarray(frames.times), summary, frame_metrics)


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


# the counters of StepStats (its `seconds` dict is saved on its own)
_TOTAL_FIELDS = tuple(f.name for f in dataclasses.fields(StepStats) if f.name != "seconds")


def _save_checkpoint(path: Path, scene: Scene, outcome: RunOutcome, frames: FrameRecorder,
                     solver: ImplicitEulerSolver) -> None:
    t = outcome.totals
    totals = {k: getattr(t, k) for k in _TOTAL_FIELDS} | {"seconds": t.seconds}
    progress = {"step": outcome.step, "wall_s": outcome.wall_s, "retried_steps": outcome.retried_steps,
                "totals": totals}
    state = outcome.state
    with atomic_write(path, "wb") as fh:  # flushed to disk before it replaces the previous checkpoint
        np.savez(fh, x=state.x.numpy(), v=state.v.numpy(), t=state.t, frames=np.stack(frames.positions),
                 times=np.asarray(frames.times), fingerprint=scene_fingerprint(scene), progress=json.dumps(progress),
                 **{f"solver_{k}": v for k, v in solver.checkpoint_arrays().items()})


def _load_checkpoint(path: Path, scene: Scene, solver: ImplicitEulerSolver) -> tuple[RunOutcome, list, list] | None:
    if not path.exists():
        return None
    arrays = read_npz(path, "checkpoint")
    source = f"checkpoint {path}"
    try:
        if str(arrays["fingerprint"]) != scene_fingerprint(scene):
            raise InputFileError(f"{source} belongs to a different scene, solver setting or tryon version; run "
                                 "again without --resume to start over")
        n = scene.model.num_vertices
        x, v = float_array(arrays, "x", source, (n, 3)), float_array(arrays, "v", source, (n, 3))
        frames = float_array(arrays, "frames", source, (None, n, 3))
        times = float_array(arrays, "times", source, (len(frames),))
        progress = json.loads(str(arrays["progress"]))
        step, t = int(progress["step"]), float(arrays["t"])
        if not (0 < step <= scene.num_steps and abs(t - step * scene.dt) < 1e-6 * max(1.0, t)):
            raise ValueError(f"step {step} at t = {t} s does not lie in this run of {scene.num_steps} steps")
        totals = progress["totals"]
        stats = StepStats(**{k: type(getattr(StepStats, k, 0))(totals[k]) for k in _TOTAL_FIELDS},
                          seconds={k: float(totals["seconds"][k]) for k in ("forces", "solve", "collision")})
        outcome = RunOutcome(ClothState(torch.from_numpy(x), torch.from_numpy(v), t), step,
                             wall_s=float(progress["wall_s"]), retried_steps=int(progress["retried_steps"]), totals=stats)
        solver.restore_arrays({k[len("solver_"):]: a for k, a in arrays.items() if k.startswith("solver_")})
    except (KeyError, ValueError, TypeError) as exc:
        raise InputFileError(f"{source} cannot be used ({exc}); run again without --resume") from exc
    return outcome, list(frames), [float(t) for t in times]


# picture(scene, positions [N,3], time, path): e.g. `tryon.render.sim_pictures.render_state_png`
ScenePicture = Callable[[Scene, np.ndarray, float, Path], None]


def run_scene(scene: Scene, out_dir: str | Path, progress: bool = True, resume: bool = False, write_objs: bool = True,
              force: bool = False, picture: ScenePicture | None = None) -> RunResult:
    """Simulate and write frames, OBJs, summary.json and (with `picture`) last_frame.png
    into out_dir. The folder is assembled in `<out_dir>.partial` (which keeps the checkpoint
    until the run ends) and renamed into place; an existing out_dir is replaced only when
    tryon wrote it (or with `force`, see `tryon.io.atomic.check_output_dir`)."""
    out_dir = check_output_dir(out_dir, force=force)
    work = claim_work_dir(out_dir.with_name(out_dir.name + ".partial"), resume=resume, force=force)
    result = simulate(scene, progress=progress, checkpoint_dir=work, resume=resume)
    publish_run(work, out_dir, scene, result, write_objs, picture, force)
    return result


def publish_run(work: Path, out_dir: Path, scene: Scene, result: RunResult, write_objs: bool = True,
                picture: ScenePicture | None = None, force: bool = False) -> None:
    """Write a run's outputs (frames.npz, obj/, last_frame.png, summary.json) into its
    working folder, drop the checkpoints and rename the folder to out_dir: the one writer
    of simulation folders (serial and time-parallel)."""
    from tryon.io.frames import save_frames_npz, write_obj_sequence

    m = scene.model
    faces, uv = m.faces.numpy(), m.mesh.uv.numpy()
    save_frames_npz(work / "frames.npz", result.positions, faces, uv=uv, times=result.times)
    if write_objs:
        write_obj_sequence(work / "obj", result.positions, faces, uv=uv)
    if picture is not None:
        picture(scene, result.positions[-1], float(result.times[-1]), work / "last_frame.png")
    with atomic_write(work / "summary.json") as fh:
        fh.write(dumps_json(result.summary, indent=2))
    (work / CHECKPOINT).unlink(missing_ok=True)
    publish_dir(work, out_dir, force=force)
