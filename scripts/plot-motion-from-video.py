"""docs/images/motion-from-video.jpg: the body's motion followed through a real video
(`tryon.perceive.video` reads the frames and follows one person, `motion_from_video` fits
the body's bones to BlazePose's 3D landmarks): each frame with its keypoints, beside the
fitted body seen from the camera's side.

    .venv/bin/python scripts/plot-motion-from-video.py VIDEO HEIGHT_CM WEIGHT_KG GENDER [START_S END_S]

The docs' picture: Sports2D's demo (BSD-3-Clause; see scripts/plot-garment-mask.py for how
to get it), 165 cm, 58 kg, female, 2.7-6.7 s.
"""

import sys
import time

import numpy as np
from PIL import Image

from tryon.body.fit import Measurements, fit_body
from tryon.body.pose import posed_vertices
from tryon.perceive.motion_from_video import motion_of_person
from tryon.perceive.video import Frames, follow_person, read_frames
from tryon.render.offscreen import Camera, RenderMesh, render_meshes

TILE_H = 260


def tile(person, vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    from PIL import ImageDraw

    img = Image.fromarray(person.image)
    draw = ImageDraw.Draw(img)
    for x, y in person.keypoints:
        draw.ellipse((x - 2, y - 2, x + 2, y + 2), fill=(0, 255, 0))
    x0, y0, x1, y1 = person.box
    pad = (y1 - y0) // 15
    crop = img.crop((max(0, x0 - pad), max(0, y0 - pad), x1 + pad, y1 + pad))
    crop = np.asarray(crop.resize((max(1, int(crop.width * TILE_H / crop.height)), TILE_H)))
    lo, hi = vertices.min(0), vertices.max(0)
    c = (lo + hi) / 2
    cam = Camera(eye=(c[0], c[1] - 6.0, c[2]), target=tuple(c), fov_deg=20)
    body = render_meshes([RenderMesh(vertices, faces, color=(0.75, 0.7, 0.65))], 200, TILE_H, cam)
    return np.hstack([crop, body])


def main() -> None:
    path, height, weight, gender = sys.argv[1], float(sys.argv[2]), float(sys.argv[3]), sys.argv[4]
    start, end = (float(sys.argv[5]), float(sys.argv[6])) if len(sys.argv) > 6 else (0.0, 1e9)
    frames = read_frames(path, fps=15.0)
    keep = [k for k, t in enumerate(frames.times) if start <= t <= end]
    frames = Frames([frames.images[k] for k in keep], frames.times[keep], frames.source)
    people = follow_person(frames)
    seen = [k for k, p in enumerate(people) if p is not None]
    shape = fit_body(Measurements(height_cm=height, weight_kg=weight, gender=gender)).shape
    t0 = time.perf_counter()
    motion, deg = motion_of_person(shape, people, frames.fps)
    travel = motion.root_translation[seen[-1]] - motion.root_translation[seen[0]]
    print(f"{len(seen)} of {len(people)} frames followed; fitted in {time.perf_counter() - t0:.1f} s, "
          f"segments {deg:.1f} deg from the landmarks on average; travel {travel[0]:+.2f} m across, "
          f"{travel[2]:+.2f} m up over {frames.times[seen[-1]] - frames.times[seen[0]]:.1f} s")
    faces = np.asarray(shape.faces)
    poses = motion.pose_matrices(shape)
    tiles = []
    for j in np.linspace(0, len(seen) - 1, 6).astype(int):
        tiles.append(tile(people[seen[j]], posed_vertices(shape, poses[seen[j]]).detach().numpy(), faces))
    width = max(t.shape[1] for t in tiles)
    tiles = [np.pad(t, ((0, 0), (0, width - t.shape[1]), (0, 0)), constant_values=255) for t in tiles]
    Image.fromarray(np.vstack([np.hstack(tiles[:3]), np.hstack(tiles[3:])])).save(
        "docs/images/motion-from-video.jpg", quality=88)


if __name__ == "__main__":
    main()
