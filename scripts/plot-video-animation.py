"""docs/images/motion-from-video-animated.jpg: frames of a real video above a garment
simulated on the motion read from it (`tryon motion from-video`, then `tryon animate`),
at the same moments, the simulated body seen from the side.

    .venv/bin/tryon motion from-video demo.mp4 --height-cm 165 --gender female --start-s 2.7 --end-s 6.7 --out out/walk
    .venv/bin/tryon drape --height-cm 165 --weight-kg 58 --gender female --garment tshirt --size S --out out/d165
    .venv/bin/tryon animate out/d165 --motion out/walk/motion.npz --out out/walk-tshirt
    .venv/bin/python scripts/plot-video-animation.py demo.mp4 2.7 out/walk-tshirt/frames.npz
"""

import sys

import numpy as np
from PIL import Image

from tryon.body.motion import BLEND_TIME
from tryon.perceive.person import detect_person, person_tile
from tryon.perceive.video import read_frames
from tryon.render.offscreen import Camera, RenderMesh, render_meshes

TIMES = (1.3, 2.0, 2.7, 3.4, 4.1)  # s into the animation (the motion starts after the blend)
W, H = 220, 300


def video_tile(image: np.ndarray) -> np.ndarray:
    p = detect_person(image, "frame")
    if p is None:
        raise SystemExit("no person found in a frame the picture needs; choose other --start-s or TIMES")
    return person_tile(image, [v / p.scale for v in p.box], H, aspect=W / H)


def sim_tile(body: np.ndarray, body_faces: np.ndarray, cloth: np.ndarray, faces: np.ndarray) -> np.ndarray:
    centre = (body.min(0) + body.max(0)) / 2
    cam = Camera(eye=centre + np.array([5.0, 0.0, 0.0]), target=centre, fov_deg=22)  # the walker's side
    return render_meshes([RenderMesh(body, body_faces, color=(0.8, 0.75, 0.7)),
                          RenderMesh(cloth, faces, color=(0.35, 0.45, 0.4), two_sided=True)], W, H, cam)


def main() -> None:
    video, start, frames_npz = sys.argv[1], float(sys.argv[2]), sys.argv[3]
    z = np.load(frames_npz)
    frames = read_frames(video, fps=15.0)
    tiles = []
    for t in TIMES:
        k = int(np.abs(z["times"] - t).argmin())
        j = int(np.abs(frames.times - (start + t - BLEND_TIME)).argmin())
        tiles.append(np.vstack([video_tile(frames.images[j]),
                                sim_tile(z["body_vertices"][k], z["body_faces"], z["positions"][k], z["faces"])]))
    Image.fromarray(np.hstack(tiles)).save("docs/images/motion-from-video-animated.jpg", quality=88)


if __name__ == "__main__":
    main()
