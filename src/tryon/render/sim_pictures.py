"""Pictures of simulations, for the commands that write them: the last frame of a scene
coloured by strain (`tryon simulate`), observed against refitted motion
(`tryon fit-fabric`) and a trajectory as a GIF (`tryon control`). The simulator and the
inverse problems take these as callables, so that the engines need no renderer."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from tryon.render.animation import write_gif
from tryon.render.colormap import add_colorbar, scalar_to_rgb
from tryon.render.offscreen import Camera, RenderMesh, render_meshes, save_png
from tryon.sim.metrics import face_strain
from tryon.sim.scene import Scene


def render_state_png(scene: Scene, x: np.ndarray, t: float, path: Path, width: int = 800, height: int = 800) -> None:
    """Picture of the cloth (coloured by strain) and the obstacles at time t."""
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


ROW_COLORS = ((0.3, 0.45, 0.8), (0.9, 0.55, 0.2), (0.35, 0.7, 0.35), (0.75, 0.3, 0.6))


def sequences_png(path: Path, faces: np.ndarray, sequences: list[np.ndarray], width: int = 320) -> None:
    """One row per sequence [T,N,3] (blue, orange, green, purple) at 1/4, 1/2, 3/4 and the
    end of the first one's frames, all seen by the same camera."""
    first = sequences[0]
    picks = sorted({max(1, round(f * (len(first) - 1))) for f in (0.25, 0.5, 0.75, 1.0)})
    cam = Camera.fit([seq[f] for seq in sequences for f in picks], view="three_quarter", margin=1.2)
    rows = []
    for k, frames in enumerate(sequences):
        color = ROW_COLORS[k % len(ROW_COLORS)]
        tiles = [render_meshes([RenderMesh(frames[f], faces, color=color)], width, width, camera=cam) for f in picks]
        rows.append(np.concatenate(tiles, axis=1))
    save_png(path, np.concatenate(rows, axis=0))


def sequence_comparison_png(path: Path, faces: np.ndarray, observed: np.ndarray, fitted: np.ndarray,
                            width: int = 320) -> None:
    """Observed (top row, blue) and refitted (bottom row, orange) frames [T,N,3] at 1/4,
    1/2, 3/4 and the end (`tryon fit-fabric`'s observed_vs_fit.png)."""
    sequences_png(path, faces, [observed, fitted], width)


def trajectory_gif(path: Path, scene: Scene, trajectory: np.ndarray, every: int = 5, width: int = 360) -> None:
    """Animated GIF of a cloth trajectory [T,N,3] of `scene` with its obstacles, seen from
    above at 45 degrees (`tryon control`'s previews)."""
    m = scene.model
    faces = m.faces.numpy()
    ob = m.obstacles.vertices_at(0.0)
    statics = [RenderMesh(v, f, color=(0.75, 0.72, 0.68), smooth=False) for _name, v, f in m.obstacles.per_obstacle(ob)]
    cam = Camera.fit(statics + [trajectory[::every].reshape(-1, 3)], view="three_quarter", margin=1.1, aspect=4 / 3,
                     elevation_deg=45.0)  # high enough to see into the basket
    images = []
    for x in trajectory[::every]:
        cloth = RenderMesh(x, faces, color=(0.85, 0.3, 0.25))
        images.append(render_meshes(statics + [cloth], width, int(width * 3 / 4), camera=cam))
    write_gif(path, images, fps=1.0 / (every * scene.dt))
