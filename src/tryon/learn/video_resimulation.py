"""The garment re-simulated on the motion read from a video (`tryon perceive --resimulate`):
what the estimated fabric does on this person doing what they did, beside the video.

The garment (its chart size for the body, or the size asked) is draped on the body the
motion was fitted on, as `tryon drape` does, in the fabric asked or else the estimated one
(the class's, when a classifier named one); then the body blends from the drape's pose
into the motion read from the video (turned to the rest heading, as motion.npz holds it)
and the garment follows (`tryon.drape.animate.garment_motion_scene`), recorded 30 times a
second from the video's first frame on. The picture puts
the video's frames above the re-simulated body and garment at the same moments, seen from
where the camera saw the person (the heading `facing_forward` took out, put back).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from tryon.body.motion import motion_start
from tryon.errors import TryonError

EDGE_LENGTH = 0.03   # m: the clips' edges (every T-shirt size dresses; about a minute for 5 s of motion)
DT = 0.01
TILE_WH = (200, 280)
FOV_DEG = 22.0


@dataclass
class Resimulation:
    times: np.ndarray        # [T] s of the video clip (0 = its first frame)
    garment: np.ndarray      # [T,N,3] garment vertices
    faces: np.ndarray
    uv: np.ndarray           # [N,2] the garment's material coordinates (m)
    body: np.ndarray         # [T,M,3] body vertices
    body_faces: np.ndarray
    size: str
    fabric: str
    summary: dict
    seconds: float


def camera_direction(heading: float) -> np.ndarray:
    """The unit vector from the body toward the camera in the motion turned to the rest
    heading: the camera looks along +y in the motion as read (`motion_from_video`), so it
    stands at -y, turned with the motion by -heading."""
    return np.array([-np.sin(heading), -np.cos(heading), 0.0])


def resimulate(video, person, asked, garment: str, fabric, size: str | None = None, edge_length: float = EDGE_LENGTH,
               progress: bool = True) -> Resimulation:
    """`garment` draped on `person` (the `BodyFit` the video's motion was fitted on, from
    the `Measurements` `asked`) in `fabric` and moved through the video's motion (`video`:
    a `VideoMotion`)."""
    from tryon.drape import DrapeRequest, drape
    from tryon.drape.animate import GarmentAtRest, garment_motion_scene
    from tryon.drape.pipeline import drape_pose
    from tryon.perceive.motion_from_video import facing_forward
    from tryon.sizing.chart import MADE_TO_MEASURE, chart_size, fitted_girths
    from tryon.sim.runner import simulate

    t0 = time.perf_counter()
    size = size or chart_size(garment, fitted_girths(person), asked.gender)[0]
    request = DrapeRequest(asked, garment=garment, size=None if size == MADE_TO_MEASURE else size,
                           fabric=fabric, edge_length=edge_length)  # a Fabric as is
    draped = drape(request, progress=progress, person=person)
    g = draped.garment
    motion = facing_forward(video.motion)
    start = motion_start(motion)  # the scene time of the video's first frame
    duration = start + float(video.frames.times[-1])
    shape = person.shape
    scene = garment_motion_scene(shape, drape_pose(shape, garment), GarmentAtRest(draped.x, g.uv, g.faces, g.corner_uv,
                                                                                  garment),
                                 fabric, motion, request.thickness, request.friction, DT, duration)
    result = simulate(scene, progress=progress)
    times = np.asarray(result.times) - start
    keep = times >= -1e-6
    bodies = np.stack([scene.model.obstacles.vertices_at(float(t)) for t in np.asarray(result.times)[keep]])
    strains = [float(m.get("max_strain", np.nan)) for m, k in zip(result.frame_metrics, keep) if k]
    return Resimulation(times[keep], np.asarray(result.positions)[keep], np.asarray(g.faces), np.asarray(g.uv), bodies,
                        np.asarray(shape.faces), size, getattr(fabric, "name", "fabric"),
                        {"drape": {k: draped.metrics.get(k) for k in ("settled", "max_strain", "penetration_pct")},
                         "clip_max_strain": float(np.nanmax(strains)) if strains else None,
                         "frame_max_strain": strains, **dict(result.summary)},
                        time.perf_counter() - t0)


def side_by_side(video, frames: list[int], sim: Resimulation, heading: float) -> np.ndarray:
    """The video's `frames` (indices into `video.frames`) cropped around the person, above
    the re-simulation at the same times seen from the camera's side (RGB uint8)."""
    from tryon.perceive.person import person_tile
    from tryon.render.offscreen import Camera, RenderMesh, render_meshes

    w, h = TILE_WH
    toward_camera = camera_direction(heading)
    tops, bottoms = [], []
    for k in frames:
        person = video.people[k]
        if person is None:
            continue
        box = [v / person.scale for v in person.box]  # in the video frame's own pixels
        tops.append(person_tile(video.frames.images[k], box, h, aspect=w / h))
        j = int(np.abs(sim.times - video.frames.times[k]).argmin())
        body = sim.body[j]
        centre = (body.min(0) + body.max(0)) / 2
        extent = float((body.max(0) - body.min(0)).max())
        distance = 1.2 * extent / (2 * np.tan(np.radians(FOV_DEG / 2)))  # the whole body, outstretched arms too
        cam = Camera(eye=centre + distance * toward_camera, target=centre, fov_deg=FOV_DEG)
        bottoms.append(render_meshes([RenderMesh(body, sim.body_faces, color=(0.8, 0.75, 0.7)),
                                      RenderMesh(sim.garment[j], sim.faces, color=(0.75, 0.3, 0.25), two_sided=True)],
                                     w, h, cam))
    if not tops:
        raise TryonError("the person is not found in any frame the picture would show")
    return np.vstack([np.hstack(tops), np.hstack(bottoms)])
