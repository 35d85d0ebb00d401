"""A picture of where every tape of `tryon.body.tape` runs on a body: front and side
views with each girth's ring and each length's line drawn in its own colour, and a legend
with the values (docs/BODY.md; `tryon body-tapes --render`)."""

from __future__ import annotations

import numpy as np

from tryon.body.anny_model import BodyShape
from tryon.body.tape import TAPES, find_landmarks, tape_measurements, tape_path

COLOURS = [(230, 25, 75), (60, 180, 75), (0, 130, 200), (245, 130, 48), (145, 30, 180), (70, 190, 190),
           (240, 50, 230), (150, 120, 0), (0, 128, 128), (128, 0, 0), (0, 0, 128), (128, 128, 0),
           (255, 90, 90), (90, 90, 255), (20, 20, 20), (120, 120, 120)]


def _project(points: np.ndarray, camera, width: int, height: int) -> np.ndarray:
    near, far = 0.1, 10.0
    mvp = camera.projection_matrix(width / height, near, far) @ camera.view_matrix()
    h = np.c_[points, np.ones(len(points))] @ mvp.T
    ndc = h[:, :3] / h[:, 3:4]
    return np.c_[(ndc[:, 0] + 1.0) * 0.5 * width, (1.0 - ndc[:, 1]) * 0.5 * height]


def render_tapes(path, shape: BodyShape, size: tuple[int, int] = (520, 900)):
    from PIL import Image, ImageDraw

    from tryon.render.colormap import label_font
    from tryon.render.offscreen import Camera, RenderMesh, render_meshes, save_png

    v = shape.vertices.detach().numpy()
    lm = find_landmarks(shape)
    values = tape_measurements(shape)
    paths = {name: tape_path(shape, name, lm) for name in TAPES}
    width, height = size
    views = []
    for view in ("front", "side"):
        cam = Camera.fit([v], view, aspect=width / height, margin=1.04)
        img = Image.fromarray(render_meshes([RenderMesh(v, shape.faces, color=(0.86, 0.78, 0.72))], width, height,
                                            camera=cam)).convert("RGB")
        draw = ImageDraw.Draw(img)
        for (name, pts), colour in zip(paths.items(), COLOURS):
            if len(pts) < 2:
                continue
            xy = _project(pts, cam, width, height)
            closed = name not in ("height", "waist_height", "crotch_height", "rise", "shoulder_width", "arm_length")
            seq = [tuple(p) for p in (np.vstack([xy, xy[:1]]) if closed else xy)]
            draw.line(seq, fill=colour, width=3)
        views.append(np.asarray(img))
    legend = Image.new("RGB", (330, height), (255, 255, 255))
    draw = ImageDraw.Draw(legend)
    font = label_font(17)
    draw.text((12, 12), "tape (ISO 8559-1 / ANSUR II)", fill=(0, 0, 0), font=font)
    for i, (name, colour) in enumerate(zip(TAPES, COLOURS)):
        y = 48 + 30 * i
        draw.rectangle([12, y + 4, 40, y + 14], fill=colour)
        draw.text((50, y), f"{name.replace('_', ' ')}: {values[name + '_cm']:.1f} cm", fill=(0, 0, 0), font=font)
    return save_png(path, np.concatenate(views + [np.asarray(legend)], axis=1))
