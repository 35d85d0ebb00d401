"""`tryon perceive`: a clip of a person moving in a garment becomes their motion, the
garment found in each frame and, with a trained fabric classifier, the fabric's class with
its probabilities and a fabric to drape with (docs/FABRIC_FROM_VIDEO.md).

The clip is read at 15 frames a second for the body's motion (`tryon.perceive.
motion_from_video`); every third frame (5 a second, at most 25: the clips the classifier
learns from) is read as the classifier reads clip renders (`tryon.perceive.frame_features`).
Classifiers that read garment codes need the garment per frame, which no estimator gives
yet: only image-only classifiers are used here.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from tryon.errors import TryonError
from tryon.fabric.wang2011 import WangFabric
from tryon.perceive.fabric_classes import FabricClasses, default_classes
from tryon.perceive.frame_features import frame_features

CLIP_FPS, CLIP_FRAMES, MIN_FRAMES = 5.0, 25, 8
MOTION_FPS = 15.0


@dataclass
class Perceived:
    """What a clip shows: the motion read from it, what the classifier reads of each of its
    frames, and the fabric class (None without a classifier)."""

    video: object                    # VideoMotion
    garment: str
    frames: list[int]                # the motion's frames the classifier reads
    features: list[dict]
    classes: FabricClasses
    probabilities: np.ndarray | None = None
    fabric: WangFabric | None = None
    notes: list[str] = field(default_factory=list)

    @property
    def fabric_class(self) -> int | None:
        return None if self.probabilities is None else int(self.probabilities.argmax())


FRAME_KEYS = ("mask_bits", "found_garment_bits", "keypoints", "visibility")  # what the classifier reads per frame


def stack_frames(features: list[dict]) -> dict[str, np.ndarray]:
    """`frame_features` of a clip's frames stacked over the frames, as a stored clip holds them."""
    return {k: np.stack([f[k] for f in features]) for k in FRAME_KEYS}


def classifier_inputs(frames: dict[str, np.ndarray]) -> tuple[torch.Tensor, torch.Tensor]:
    """Masks [1,T,2,64,64] and keypoints [1,T,99] as `tryon.learn.fabric_video` reads clips."""
    from tryon.learn.fabric_video import frame_inputs

    masks, kp = frame_inputs(*(frames[k] for k in FRAME_KEYS))
    return torch.from_numpy(masks[None]), torch.from_numpy(kp[None])


def check_image_only(model, name: str) -> None:
    """Refuse a classifier that reads garment codes: nothing gives the garment per frame yet."""
    from tryon.learn.fabric_video import method_parts

    if method_parts(model.method)[1]:
        raise TryonError(f"{name} reads garment codes ({model.method}), which need the garment in each frame; no "
                         "estimator gives it yet: use an image-only model (tryon train fabric-video --method "
                         "image-only-temporal)")


def classify(model, frames: dict[str, np.ndarray]) -> np.ndarray:
    """Class probabilities of an image-only classifier on a clip's frames (`FRAME_KEYS`
    stacked over the frames: `stack_frames`, or a stored clip's `frame_*` arrays)."""
    check_image_only(model, "the classifier")
    masks, keypoints = classifier_inputs(frames)
    codes = torch.zeros(1, masks.shape[1], 1)  # unread by an image-only model; it sets the clip's length
    with torch.no_grad():
        return torch.softmax(model(masks, keypoints, codes), -1)[0].numpy()


def clip_frames(times: np.ndarray, found: np.ndarray, fps: float = CLIP_FPS, count: int = CLIP_FRAMES,
                tolerance: float = 0.1) -> list[int]:
    """Indices of the frames nearest every 1/fps from the first frame with the person, at
    most `count`, each within `tolerance` s of its time (a gap in the source ends them)."""
    first = int(np.argmax(found)) if found.any() else None
    if first is None:
        return []
    picked = []
    for k in range(count):
        want = times[first] + k / fps
        i = int(np.abs(times - want).argmin())
        if abs(times[i] - want) > tolerance:
            break
        picked.append(i)
    return picked


def perceive_video(source, shape, garment: str, start_s: float = 0.0, classifier: str | None = None,
                   folder_fps: float = MOTION_FPS) -> Perceived:
    """Read `source` (a video file, or a folder of frames taken `folder_fps` apart) from `start_s`:
    the motion of the person in it fitted on `shape`, the garment (`garment`) found in the
    classifier's frames, and with `classifier` (a model file of `tryon train fabric-video`)
    the fabric class."""
    from tryon.learn.train_fabric_video import load_classifier
    from tryon.perceive.motion_from_video import read_video_motion

    classes = default_classes()
    model = load_classifier(classifier)[0] if classifier else None  # a bad model file fails before the work
    if model is not None:
        check_image_only(model, classifier)
        if model.classes != classes.count:
            raise TryonError(f"{classifier} names {model.classes} classes, the fabric classes are {classes.count}")
    duration = (CLIP_FRAMES - 1) / CLIP_FPS
    vm = read_video_motion(source, shape, fps=MOTION_FPS, start_s=start_s, end_s=start_s + duration + 1e-6,
                           folder_fps=folder_fps)
    found = np.array([p is not None for p in vm.people])
    picked = clip_frames(vm.frames.times, found)
    features, box = [], None
    for k in picked:
        p = vm.people[k]
        box = p.box if p is not None else box  # a frame without the person: empty, cropped where they were
        features.append(frame_features(p.image if p is not None else None, p, garment, box=box)[0])
    out = Perceived(vm, garment, picked, features, classes)
    if len(features) < MIN_FRAMES:
        raise TryonError(f"{source}: the clip gives {len(features)} frames at {CLIP_FPS:g} a second from where the "
                         f"person is first found; at least {MIN_FRAMES} ({(MIN_FRAMES - 1) / CLIP_FPS:g} s) are needed")
    if model is None:
        out.notes.append("no fabric classifier given (--classifier): the class is not named; none is shipped yet")
        return out
    out.probabilities = classify(model, stack_frames(features))
    out.fabric = out.classes.centre_fabric(out.fabric_class)
    return out


def frames_picture(p: Perceived, count: int = 6) -> np.ndarray:
    """Up to `count` of the classifier's frames: the person tinted blue, the garment found
    red (RGB uint8, one row)."""
    from tryon.perceive.garment_mask import garment_mask
    from tryon.perceive.person import person_tile

    tiles = []
    for k in p.frames[:: max(1, len(p.frames) // count)][:count]:
        person = p.video.people[k]
        if person is None:
            continue
        m = garment_mask(person.image, person.mask, person.keypoints, p.garment)
        img = person.image.astype(np.float64)
        rest = (person.mask > 0.5) & ~m
        img[m] = 0.45 * img[m] + (140, 0, 0)
        img[rest] = 0.6 * img[rest] + (0, 0, 100)
        tiles.append(person_tile(img.astype(np.uint8), person.box, 260, pad=1 / 12))
    if not tiles:
        return np.zeros((260, 260, 3), np.uint8)
    return np.hstack(tiles)


def write_perceived(p: Perceived, out: Path, sim=None) -> dict:
    """motion.npz, body.obj, frames.png, report.json, (with a class) fabric.json and (with
    `sim`, a `video_resimulation.Resimulation`) resimulated.npz and resimulated.png in `out`."""
    from tryon.io.json_safe import dumps_json
    from tryon.io.mesh_io import write_obj
    from tryon.perceive.motion_from_video import facing_forward
    from tryon.render.offscreen import save_png

    facing_forward(p.video.motion).save(out / "motion.npz")
    write_obj(out / "body.obj", p.video.shape.vertices.detach().numpy(), np.asarray(p.video.shape.faces))
    save_png(out / "frames.png", frames_picture(p))
    report = {"motion": p.video.report(), "classifier_frames": len(p.features),
              "garment_found_frames": int(sum(f["found_garment_bits"].any() for f in p.features)), "notes": p.notes,
              "fabric": None}
    if p.probabilities is not None:
        c = p.fabric_class
        top = np.argsort(-p.probabilities)[:5]
        report["fabric"] = {"class": p.classes.name(c), "probability": float(p.probabilities[c]),
                            "top": [{"class": p.classes.name(int(k)), "probability": float(p.probabilities[k])}
                                    for k in top],
                            "nearest_presets": p.classes.nearest_measured(c, 3), "file": "fabric.json"}
        with (out / "fabric.json").open("w") as fh:
            fh.write(json.dumps(p.fabric.to_arcsim_dict(), indent=1))
    if sim is not None:
        from tryon.io.frames import save_frames_npz
        from tryon.learn.video_resimulation import side_by_side
        from tryon.perceive.motion_from_video import camera_heading

        save_frames_npz(out / "resimulated.npz", sim.garment, sim.faces, uv=sim.uv, times=sim.times,
                        body_vertices=sim.body.astype(np.float32), body_faces=sim.body_faces,
                        max_strain=np.asarray(sim.summary["frame_max_strain"], np.float32))
        save_png(out / "resimulated.png", side_by_side(p.video, p.frames[::max(1, len(p.frames) // 6)][:6], sim,
                                                       camera_heading(p.video.motion)))
        report["resimulation"] = {"size": sim.size, "fabric": sim.fabric, "frames": int(len(sim.times)),
                                  "max_strain": float(sim.summary.get("clip_max_strain") or float("nan")),
                                  "final_max_strain": float(sim.summary.get("final_max_strain", float("nan"))),
                                  "seconds": sim.seconds, "summary": sim.summary, "files": ["resimulated.npz",
                                                                                           "resimulated.png"]}
    with (out / "report.json").open("w") as fh:
        fh.write(dumps_json(report, indent=2))
    return report
