"""`tryon animate DIR --motion walk`: a draped garment follows its body through a motion.

The drape in DIR (written by `tryon drape`) holds the garment at rest on the person in
the A-pose and the person's Anny parameters. The body blends from the A-pose into the
motion (`tryon.body.motion.motion_keyframes`) and plays it as a key-framed collision
obstacle; the garment is simulated through it (contact, friction, gravity). Outputs in
the animation directory: frames.npz (garment and body per frame), preview.gif,
metrics.json (per frame: strain, penetration, intersections), report.json and
last_frame.png.
"""

from __future__ import annotations

import functools
import shutil
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from tryon.body.anny_model import ShapeParams, body_model
from tryon.body.motion import BLEND_TIME, load_motion, motion_keyframes
from tryon.drape.pipeline import drape_pose
from tryon.errors import TryonError
from tryon.fabric import load_fabric
from tryon.garment.pattern import Pattern
from tryon.garment.triangulate import remesh_pattern
from tryon.sim.integrator import StepOptions
from tryon.sim.origin import PatternOrigin
from tryon.sim.scene import Scene
from tryon.io.json_safe import dumps_json

FRAME_TIME = 1.0 / 30.0


def load_drape(drape_dir: str | Path) -> dict:
    from tryon.drape.pipeline import STATE_FILE, load_state

    return load_state(Path(drape_dir) / STATE_FILE)


def drape_print(drape_dir: str | Path, state: dict):
    """(the placed print, the garment it is on) of a drape made with `--print`, else None.
    The image is the copy the drape wrote (print.png), so the drape folder stands alone."""
    from tryon.drape.dress import DressedGarment
    from tryon.garment.prints import GraphicPrint

    request = state["request"]
    if not request.get("print_image"):
        return None
    copy = Path(drape_dir) / "print.png"
    garment = DressedGarment.from_state(state)
    image = copy if copy.is_file() else request["print_image"]
    return GraphicPrint.load(image, float(request.get("print_width_cm", 24.0))).placed_on(garment.pattern), garment


def animation_scene(drape_dir: str | Path, motion: str = "walk", dt: float = 0.01, duration: float | None = None,
                    blend_time: float = BLEND_TIME, repeat: int = 1) -> Scene:
    """The draped garment of `drape_dir` as cloth and its body moving through `motion`
    (a built-in name, .npz or .bvh; a cyclic one played `repeat` times) as a key-framed
    obstacle, ready to simulate."""
    if not 0.001 <= dt <= 1 / 30:
        raise TryonError(f"time step {dt} s is outside 0.001-0.033 s")
    state = load_drape(drape_dir)
    request = state["request"]
    shape = body_model().rest_shape(ShapeParams.from_dict(state["body_params"]))
    start_pose = drape_pose(shape, request.get("garment", ""))
    body_motion = load_motion(motion, shape).repeated(repeat)
    printed = drape_print(drape_dir, state)
    cloth = GarmentAtRest(state["x"], state["uv"], state["faces"], state["corner_uv"], state["pattern"].get("name", "garment"))
    scene = garment_motion_scene(shape, start_pose, cloth, load_fabric(request["fabric"]), body_motion,
                                 request["thickness"], request["friction"], dt, duration, blend_time,
                                 regions=[] if printed is None else [printed[0].region(printed[1])],
                                 expected_body=state["body_vertices"], source=str(drape_dir))
    scene.spec = {"animation": {"drape": str(Path(drape_dir).resolve()), "motion": str(motion), "dt": dt,
                                "duration": scene.duration, "repeat": int(repeat), "blend_time": blend_time,
                                "motion_frames": int(body_motion.num_frames),
                                "print": None if printed is None else printed[0].describe(printed[1])}}
    scene.origin = PatternOrigin(float(request["edge_length"]), np.asarray(state["face_panel"]),
                                 functools.partial(remesh_pattern, Pattern.from_dict(state["pattern"])))
    return scene


@dataclass
class GarmentAtRest:
    """A garment's rest positions on its body, its material coordinates and faces."""

    x: np.ndarray
    uv: np.ndarray
    faces: np.ndarray
    corner_uv: np.ndarray
    name: str = "garment"


def garment_motion_scene(shape, start_pose: np.ndarray, garment: GarmentAtRest, fabric, body_motion,
                         thickness: float, friction: float, dt: float = 0.01, duration: float | None = None,
                         blend_time: float = BLEND_TIME, regions: list | None = None,
                         expected_body: np.ndarray | None = None, source: str = "garment") -> Scene:
    """`garment` (at rest on `shape` posed in `start_pose`) as cloth, and the body blending
    from that pose into `body_motion` as a key-framed obstacle. `expected_body`: the body
    the garment rests on, checked against the skinned start (a drape made with another
    body model version does not match)."""
    from tryon.sim.mesh import ClothMesh
    from tryon.sim.model import ClothModel, CollisionSettings
    from tryon.sim.obstacles import Motion, Obstacle

    if not 0.001 <= dt <= 1 / 30:
        raise TryonError(f"time step {dt} s is outside 0.001-0.033 s")
    frames, times = motion_keyframes(shape, body_motion, start_pose, blend_time=blend_time)
    if expected_body is not None and np.abs(frames[0] - expected_body).max() > 1e-3:
        raise TryonError(f"{source}: the stored body does not match its parameters (drape made with another body "
                         f"model version?); run `tryon drape` again")
    faces = shape.faces.numpy() if hasattr(shape.faces, "numpy") else np.asarray(shape.faces)
    body = Obstacle("body", frames[0], faces, Motion(keyframes=frames, keyframe_times=times))
    cloth = ClothMesh(torch.as_tensor(garment.x), torch.as_tensor(garment.uv), torch.as_tensor(garment.faces),
                      name=garment.name, face_uv=torch.as_tensor(garment.corner_uv))
    model = ClothModel(cloth, fabric, obstacles=[body],
                       collision=CollisionSettings(thickness=thickness, friction=friction, self_friction=0.3),
                       regions=regions or [])
    total = float(times[-1]) if duration is None else float(duration)
    if total <= 0:
        raise TryonError(f"animation duration must be positive, got {total}")
    return Scene(name=f"animate-{body_motion.name}", model=model, dt=dt, duration=total, frame_time=FRAME_TIME,
                 options=StepOptions(), description=f"{cloth.name} on a body doing '{body_motion.name}'", spec={})


def frame_metrics(scene: Scene, positions: np.ndarray, times: np.ndarray, base: list[dict]) -> list[dict]:
    """Per frame: the simulator's metrics plus penetration of the garment into the body."""
    from tryon.drape.fit_metrics import penetration

    model = scene.model
    out = []
    for x, t, m in zip(positions, times, base):
        pen = penetration(x, model.obstacles.vertices_at(float(t)), model.obstacles.faces)
        out.append({"time": float(t), **m, "penetration_pct": pen["penetration_pct"],
                    "deepest_penetration_mm": pen["deepest_penetration_mm"]})
    return out


def render_preview(scene: Scene, positions: np.ndarray, times: np.ndarray, size=(360, 480), progress: bool = True) -> list[np.ndarray]:
    """Front three-quarter renders of body and garment, one per frame, framed once."""
    from tryon.drape.outputs import SKIN
    from tryon.render.appearance import fabric_colors
    from tryon.render.offscreen import Camera, RenderMesh, render_meshes

    model = scene.model
    colors = fabric_colors(model.fabric.name, model.mesh.uv.numpy())
    drape_dir = scene.spec["animation"]["drape"]
    printed = drape_print(drape_dir, load_drape(drape_dir)) if scene.spec["animation"].get("print") else None
    if printed is not None:  # per vertex: a preview's resolution
        from tryon.garment.prints import panel_xy

        pr, garment = printed
        on = np.zeros(len(colors), bool)
        on[np.unique(garment.faces[pr.touched_faces(garment)])] = True
        ink = pr.rgba_at(panel_xy(model.mesh.uv.numpy()))
        a = np.where(on, ink[:, 3], 0.0)[:, None]
        colors = (1 - a) * colors + a * ink[:, :3]
    faces = model.faces.numpy()
    bodies = [model.obstacles.vertices_at(float(t)) for t in times]
    cam = Camera.fit([np.concatenate([bodies[0], bodies[-1], positions[0]])], "three_quarter", aspect=size[0] / size[1], margin=1.15)
    images = []
    for x, b in tqdm(list(zip(positions, bodies)), desc="rendering", unit="frame", disable=not progress, leave=False):
        meshes = [RenderMesh(b, model.obstacles.faces, color=SKIN, two_sided=False), RenderMesh(x, faces, vertex_colors=colors)]
        images.append(render_meshes(meshes, size[0], size[1], camera=cam))
    return images


def animate(drape_dir: str | Path, motion: str = "walk", out: str | Path | None = None, dt: float = 0.01,
            progress: bool = True, resume: bool = False, run=None, duration: float | None = None,
            force: bool = False, repeat: int = 1) -> dict:
    """Simulate the drape in `drape_dir` through `motion` and write the outputs (see the
    module docstring) into `out` (default DIR/animation-<motion>). `duration` (s) cuts the
    motion short (default: the whole motion plus the blend from the drape's pose); a cyclic
    motion plays `repeat` times. `run(scene, work_dir,
    progress, resume)` may replace the serial simulation (e.g. a time-parallel run); it
    returns a `tryon.sim.runner.RunResult`."""
    from tryon.io.atomic import atomic_output_dir, atomic_write, check_output_dir, claim_work_dir
    from tryon.io.frames import save_frames_npz
    from tryon.render.animation import write_gif
    from tryon.render.sim_pictures import render_state_png
    from tryon.sim.runner import simulate

    t0 = time.perf_counter()
    out = Path(out) if out is not None else Path(drape_dir) / f"animation-{Path(str(motion)).stem}"
    check_output_dir(out, force=force)
    scene = animation_scene(drape_dir, motion, dt=dt, duration=duration, repeat=repeat)
    work = claim_work_dir(out.with_name(out.name + ".checkpoint"), resume=resume, force=force)
    if run is None:
        result = simulate(scene, progress=progress, checkpoint_dir=work, resume=resume)
    else:
        result = run(scene, work, progress, resume)
    metrics = frame_metrics(scene, result.positions, result.times, result.frame_metrics)
    bodies = np.stack([scene.model.obstacles.vertices_at(float(t)) for t in result.times])
    images = render_preview(scene, result.positions, result.times, progress=progress)
    report = {
        "drape": str(drape_dir), "motion": scene.spec["animation"]["motion"], "frames": len(metrics),
        **result.summary,
        "max_penetration_pct": max(m["penetration_pct"] for m in metrics),
        "mean_penetration_pct": float(np.mean([m["penetration_pct"] for m in metrics])),
        "max_strain": max(m["max_strain"] for m in metrics),
        "wall_s": time.perf_counter() - t0,
    }
    m = scene.model
    with atomic_output_dir(out, force=force) as tmp:
        save_frames_npz(tmp / "frames.npz", result.positions, m.faces.numpy(), uv=m.mesh.uv.numpy(), times=result.times,
                        body_vertices=bodies, body_faces=m.obstacles.faces)
        write_gif(tmp / "preview.gif", images, fps=1.0 / FRAME_TIME)
        render_state_png(scene, result.positions[-1], float(result.times[-1]), tmp / "last_frame.png")
        with atomic_write(tmp / "metrics.json") as fh:
            fh.write(dumps_json(metrics, indent=1))
        with atomic_write(tmp / "report.json") as fh:
            fh.write(dumps_json(report, indent=2))
    shutil.rmtree(work)
    return report
