"""The body from photos: one to four pictures of a shopper, with their stature and gender
(and, if they give it, their weight), become the body a garment is draped on.

Each photo goes through the person finder (`tryon.perceive.person`: BlazePose's mask and
keypoints, or a one-line refusal naming the photo). The crops go through the shipped
multi-view regression (`tryon.learn.body_photos`), which gives every tape measurement
with its spread. Without a weight the network starts from the weight typical of the
stature and is told so; the weight is then read off the girths it found
(`WeightModel.from_girths`). Anny is fitted to the eight measurements the photo dataset's
bodies were fitted to (`DRAWN`), so the body from photos is built the way the training
bodies were.
"""

from __future__ import annotations

import math
import numbers
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from tryon.body.fit import (AGE_RANGE, BMI_RANGE, GENDERS, GIRTH_RANGE_CM, HEIGHT_RANGE_CM, TAPE_RANGE_CM, BodyFit,
                           Measurements, fit_body)
from tryon.errors import TryonError
from tryon.io.threads import one_torch_thread
from tryon.learn.body_photos import WEIGHT_TAPES, PhotoModel, check_views, condition, load_model, silhouette_profile
from tryon.perceive.person import K, PersonCrop, PersonInPhoto, find_person, person_crop

MODEL_PATH = Path(__file__).resolve().parent / "models" / "body-photos.npz"
# the tapes the body is fitted to: those the photo dataset's bodies were fitted to
FITTED = ("chest", "waist_navel", "hip", "neck", "thigh", "shoulder_width", "arm_length", "crotch_height")
# measurements.json's names -> the tape; the waist is measured at the navel, as ANSUR II's
# waistcircumference is
REPORTED = {"chest_cm": "chest", "waist_cm": "waist_navel", "hip_cm": "hip", "neck_cm": "neck", "thigh_cm": "thigh",
            "inseam_cm": "crotch_height", "arm_length_cm": "arm_length", "shoulder_width_cm": "shoulder_width"}

_MODELS: dict[str, PhotoModel] = {}


def shipped_model(path: str | Path | None = None) -> PhotoModel:
    """The body-from-photos model (the shipped one by default), loaded once."""
    path = Path(path) if path is not None else MODEL_PATH
    if not path.is_file():
        raise TryonError(f"no body-from-photos model at {path}; train one with tryon train body-photos")
    key = str(path.resolve())
    if key not in _MODELS:
        _MODELS[key] = load_model(path)
    return _MODELS[key]


@dataclass
class PhotoMeasurements:
    """Every tape the network read (cm), its spread (cm, one sd), and the weight."""

    tapes: dict[str, float]
    sd: dict[str, float]
    weight_kg: float
    weight_given: bool
    weight_sd_log: float  # spread of log weight read off the girths (0 when given)
    cameras: np.ndarray   # [V,5] each view's weak-perspective camera on its crop
    joints: np.ndarray    # [J,3] body-frame joints (stature units, hip-centred)


def read_measurements(model: PhotoModel, crops: list[PersonCrop], height_cm: float, gender: str,
                      weight_kg: float | None) -> PhotoMeasurements:
    """The network's measurements of one person seen in `crops` (any order, 1-8 views)."""
    check_views(len(crops))
    g = float(GENDERS[gender])
    given = weight_kg is not None
    w = float(weight_kg) if given else float(model.weight.from_height(height_cm, g)[0])
    masks = np.stack([c.mask for c in crops]).astype(np.float32)
    kp = np.stack([c.keypoints for c in crops]).astype(np.float32)
    with torch.no_grad():
        out = model.net(torch.from_numpy(masks)[None, :, None], torch.from_numpy(kp)[None],
                        torch.from_numpy(silhouette_profile(masks, kp))[None], torch.ones(1, len(crops)),
                        torch.from_numpy(condition([height_cm], [w], [g], given)))
    resid = out["residual"][0].numpy().astype(np.float64)
    log = model.baseline.log_mean(height_cm, w, g) + resid * model.baseline.sd
    values = np.exp(log)
    spread = values * np.exp(out["log_sd"][0].clamp(-4.0, 3.0).numpy()) * model.baseline.sd
    tapes = dict(zip(model.tapes, (float(v) for v in values)))
    sd = dict(zip(model.tapes, (float(v) for v in spread)))
    weight_sd_log = 0.0
    if not given:
        girths = np.array([[tapes[n] for n in WEIGHT_TAPES]])
        w = float(model.weight.from_girths(height_cm, g, girths)[0])
        # the regression's own spread and each girth's, carried through its coefficient
        rel = np.array([sd[n] / tapes[n] for n in WEIGHT_TAPES])
        weight_sd_log = float(np.sqrt(model.weight.sd_from_girths ** 2 + ((model.weight.coef_tapes[-len(WEIGHT_TAPES):] * rel) ** 2).sum()))
    return PhotoMeasurements(tapes, sd, w, given, weight_sd_log, out["camera"][0].numpy(), out["joints"][0].numpy())


@dataclass
class PhotoBody:
    """A body estimated from photos: the fit, what the network read, and the people found."""

    fit: BodyFit
    read: PhotoMeasurements
    height_cm: float
    gender: str
    people: list[PersonInPhoto]
    crops: list[PersonCrop]
    notes: list[str] = field(default_factory=list)
    timings: dict[str, float] = field(default_factory=dict)
    model: str = ""
    asked: dict[str, float] = field(default_factory=dict)  # the tapes the body was fitted to (cm)
    age: float = 30.0

    def request(self) -> Measurements:
        """The numbers the body was fitted to: `fit_body` of them is `self.fit`."""
        return Measurements(height_cm=self.height_cm, gender=self.gender, weight_kg=self.read.weight_kg, age=self.age,
                            **self.asked)

    def measurements(self) -> dict[str, float]:
        """measurements.json: stature, weight, the reported tapes (as the network read
        them) and a spread `<name>_sd` for each."""
        out: dict[str, float] = {"height_cm": self.height_cm, "weight_kg": round(self.read.weight_kg, 2),
                                 "weight_given": self.read.weight_given}
        if not self.read.weight_given:
            out["weight_kg_sd"] = round(self.read.weight_kg * self.read.weight_sd_log, 2)
        for name, tape in REPORTED.items():
            out[name] = round(self.read.tapes[tape], 2)
            out[f"{name}_sd"] = round(self.read.sd[tape], 2)
        return out


def _clip_to_range(name: str, value: float, notes: list[str]) -> float:
    lo, hi = TAPE_RANGE_CM.get(name) or GIRTH_RANGE_CM.get(name) or (-math.inf, math.inf)
    if lo <= value <= hi:
        return value
    clipped = min(max(value, lo), hi)
    notes.append(f"the photos read a {name.replace('_', ' ')} of {value:.1f} cm, outside {lo:g}-{hi:g} cm; "
                 f"the body is fitted to {clipped:.1f} cm")
    return clipped


def fit_read_body(height_cm: float, gender: str, weight_kg: float, age: float, tapes: dict[str, float],
                  notes: list[str]) -> tuple[BodyFit, dict[str, float]]:
    """Anny fitted to the tapes read off the photos (those in `FITTED`, each kept in the
    supported range with a note): (the fit, the tapes asked in cm)."""
    asked = {f"{n}_cm": _clip_to_range(n, tapes[n], notes) for n in FITTED}
    with one_torch_thread():  # set here: a collision query since may have put torch back on every core
        return fit_body(Measurements(height_cm=height_cm, gender=gender, weight_kg=weight_kg, age=age, **asked)), asked


def weight_in_range(height_cm: float, gender: str, weight_kg: float, notes: list[str]) -> float:
    """A weight read off the photos, kept inside the supported BMI range with a note."""
    lo, hi = BMI_RANGE[gender]
    bmi = weight_kg / (height_cm / 100.0) ** 2
    if lo <= bmi <= hi:
        return weight_kg
    kept = min(max(bmi, lo), hi) * (height_cm / 100.0) ** 2
    notes.append(f"the photos read a weight of {weight_kg:.1f} kg (BMI {bmi:.1f}), outside BMI {lo:g}-{hi:g}; "
                 f"the body is fitted to {kept:.1f} kg")
    return kept


def _check_person(height_cm: float, gender: str, weight_kg: float | None, age: float) -> None:
    if gender not in GENDERS:
        raise TryonError(f"gender {gender!r}: give female or male")
    for name, value, (lo, hi), unit in (("height", height_cm, HEIGHT_RANGE_CM, "cm"), ("age", age, AGE_RANGE, "years")):
        if not (isinstance(value, numbers.Real) and lo <= float(value) <= hi):
            raise TryonError(f"{name} {value} {unit} is outside the supported {lo:g}-{hi:g} {unit}")
    if weight_kg is not None:
        Measurements(height_cm=float(height_cm), gender=gender, weight_kg=float(weight_kg), age=float(age)).validate()


def body_from_photos(photos: list[tuple[str, np.ndarray]], height_cm: float, gender: str,
                     weight_kg: float | None = None, age: float = 30.0, model: str | Path | None = None) -> PhotoBody:
    """The body of the person in `photos` ((name, RGB uint8 [H,W,3]) each; 1-4 views of the
    same person, any sides, any order). Raises `PersonNotFound` naming the photo that
    shows no whole standing person."""
    _check_person(height_cm, gender, weight_kg, age)
    check_views(len(photos))
    net = shipped_model(model)
    with one_torch_thread():  # small tensors: see tryon.io.threads
        return _body_from_photos(photos, height_cm, gender, weight_kg, age, model, net)


def _body_from_photos(photos, height_cm, gender, weight_kg, age, model, net) -> PhotoBody:
    t0 = time.perf_counter()
    people = [find_person(image, name) for name, image in photos]
    crops = [person_crop(p) for p in people]
    t1 = time.perf_counter()
    read = read_measurements(net, crops, height_cm, gender, weight_kg)
    t2 = time.perf_counter()
    notes = [n for p in people for n in p.notes]
    if weight_kg is None:
        read.weight_kg = weight_in_range(height_cm, gender, read.weight_kg, notes)
    fit, asked = fit_read_body(float(height_cm), gender, read.weight_kg, float(age), read.tapes, notes)
    t3 = time.perf_counter()
    return PhotoBody(fit, read, float(height_cm), gender, people, crops, notes + list(fit.notes),
                     {"find_people_s": t1 - t0, "network_s": t2 - t1, "fit_s": t3 - t2, "total_s": t3 - t0},
                     str(model or MODEL_PATH), asked, float(age))


def body_from_image_files(paths: list[str], height_cm: float, gender: str, weight_kg: float | None = None,
                          age: float = 30.0, model: str | Path | None = None) -> PhotoBody:
    """`body_from_photos` on photo files (each read upright by its EXIF tag)."""
    from tryon.perceive.images import load_photo

    _check_person(height_cm, gender, weight_kg, age)
    check_views(len(paths))
    return body_from_photos([(str(p), load_photo(p)) for p in paths], height_cm, gender, weight_kg, age, model)


# ----------------------------------------------------------------------------- overlays
def _arm_angle_deg(p: PersonInPhoto) -> float:
    """How far the arms hang from the body in the photo (2D, both arms averaged)."""
    kp = p.keypoints
    angles = []
    for s, w in ((K["left_shoulder"], K["left_wrist"]), (K["right_shoulder"], K["right_wrist"])):
        d = kp[w] - kp[s]
        angles.append(math.degrees(math.atan2(abs(d[0]), max(d[1], 1e-6))))
    return float(np.clip(np.mean(angles), 5.0, 70.0))


# BlazePose keypoints and the Anny joints at the same places (the person's left is Anny's .L)
ALIGN = (("left_shoulder", "upperarm01.L"), ("right_shoulder", "upperarm01.R"), ("left_elbow", "lowerarm01.L"),
         ("right_elbow", "lowerarm01.R"), ("left_wrist", "wrist.L"), ("right_wrist", "wrist.R"),
         ("left_hip", "upperleg01.L"), ("right_hip", "upperleg01.R"), ("left_knee", "lowerleg01.L"),
         ("right_knee", "lowerleg01.R"), ("left_ankle", "foot.L"), ("right_ankle", "foot.R"))


@dataclass
class PhotoCamera:
    """A weak-perspective camera on a photo: turned by `yaw_deg` about the vertical, image
    x = ox + scale * (cos yaw * x + sin yaw * y), image y = oy - scale * z (px, world m)."""

    yaw_deg: float
    scale: float
    ox: float
    oy: float
    rms_px: float

    def project(self, points: np.ndarray) -> np.ndarray:
        a = math.radians(self.yaw_deg)
        u = math.cos(a) * points[:, 0] + math.sin(a) * points[:, 1]
        return np.stack([self.ox + self.scale * u, self.oy - self.scale * points[:, 2]], 1)


def align_camera(joints: dict[str, np.ndarray], p: PersonInPhoto) -> PhotoCamera:
    """The camera that best lays the body's joints on the person's keypoints: every yaw in
    whole 5-degree steps, scale and offset by least squares for each (visible keypoints)."""
    pts = np.array([joints[j] for _, j in ALIGN])
    kp = np.array([p.keypoints[K[k]] for k, _ in ALIGN])
    w = (np.array([p.visibility[K[k]] for k, _ in ALIGN]) > 0.3).astype(float)
    if w.sum() < 4:
        w[:] = 1.0
    best = None
    for deg in range(0, 360, 5):
        a = math.radians(deg)
        u = math.cos(a) * pts[:, 0] + math.sin(a) * pts[:, 1]
        z = pts[:, 2]
        mu = lambda x: float((w * x).sum() / w.sum())  # noqa: E731
        du, dz, dx, dy = u - mu(u), z - mu(z), kp[:, 0] - mu(kp[:, 0]), kp[:, 1] - mu(kp[:, 1])
        scale = float((w * (du * dx - dz * dy)).sum() / max((w * (du * du + dz * dz)).sum(), 1e-12))
        ox, oy = mu(kp[:, 0]) - scale * mu(u), mu(kp[:, 1]) + scale * mu(z)
        cam = PhotoCamera(float(deg), scale, ox, oy, 0.0)
        err = cam.project(pts) - kp
        cam.rms_px = float(np.sqrt((w * (err ** 2).sum(1)).sum() / w.sum()))
        if scale > 0 and (best is None or cam.rms_px < best.rms_px):
            best = cam
    if best is None:  # the finder refuses people who are not upright, so only degenerate keypoints get here
        raise TryonError(f"{p.name}: the body cannot be laid on the person's keypoints (no upright camera fits them)")
    return best


def fit_overlay(pb: PhotoBody, view: int) -> tuple[np.ndarray, PhotoCamera]:
    """The photo with the fitted body's outline and joints drawn over it (RGB uint8): the
    body posed with the photo's arm angle, seen through the camera that lays its joints on
    the person's keypoints (`align_camera`)."""
    from PIL import Image, ImageDraw
    from scipy.ndimage import binary_erosion

    from tryon.body.pose import arm_pose, posed_body

    p = pb.people[view]
    shape = pb.fit.shape
    body = posed_body(shape, arm_pose(shape, _arm_angle_deg(p)))
    cam = align_camera(body.heads, p)
    xy = cam.project(body.vertices)
    h, w = p.image.shape[:2]
    sil = Image.new("L", (w, h), 0)
    draw = ImageDraw.Draw(sil)
    for f in body.faces:
        draw.polygon([tuple(xy[i]) for i in f], fill=255)
    inside = np.asarray(sil) > 0
    edge = inside & ~binary_erosion(inside, iterations=max(1, h // 300))
    img = p.image.astype(np.float32)
    img[inside] = 0.75 * img[inside] + 0.25 * np.array([60.0, 220.0, 120.0])
    img[edge] = [40.0, 230.0, 90.0]
    out = Image.fromarray(img.clip(0, 255).astype(np.uint8))
    d = ImageDraw.Draw(out)
    r = max(2, h // 160)
    for x, y in cam.project(np.array([body.heads[j] for _, j in ALIGN])):
        d.ellipse([x - r, y - r, x + r, y + r], fill=(255, 60, 200))
    return np.asarray(out), cam


def write_photo_body(pb: PhotoBody, out: Path) -> dict:
    """body.obj, measurements.json, overlay-NN.png per view and report.json into `out`."""
    from tryon.io.json_safe import dumps_json
    from tryon.io.mesh_io import write_obj
    from tryon.render.offscreen import save_png

    from tryon.body.pose import posed_body

    body = posed_body(pb.fit.shape, "a")
    write_obj(out / "body.obj", body.vertices, body.faces)
    measurements = pb.measurements()
    (out / "measurements.json").write_text(dumps_json(measurements, indent=2))
    overlays = []
    for i, p in enumerate(pb.people):
        name = f"overlay-{i:02d}-{Path(p.name).stem}.png"
        picture, cam = fit_overlay(pb, i)
        save_png(out / name, picture)
        overlays.append({"image": p.name, "overlay": name, "people_found": p.people_found, "yaw_deg": cam.yaw_deg,
                         "joints_to_keypoints_rms_px": round(cam.rms_px / p.scale, 1)})
    report = {"measurements": measurements, "read_cm": pb.read.tapes, "read_sd_cm": pb.read.sd,
              "body": pb.fit.report(), "views": overlays, "notes": pb.notes, "timings": pb.timings,
              "model": pb.model}
    (out / "report.json").write_text(dumps_json(report, indent=2))
    return report
