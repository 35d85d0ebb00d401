"""Photo datasets for the body from photos: people whose girths vary at a given stature
and weight as real people's do, photographed standing from several sides, and what the
person finder sees in each picture.

A sample draws a gender, an age, a stature and a BMI uniformly in the ranges, then the
rest of the person from the ANSUR II prior given stature, weight and age (chest, waist,
hip, neck, thigh, shoulder width, arm length, crotch height: `AnthropometricPrior.sample`,
within 2.5 sigma), and fits Anny to all of them (`fit_body`). Anny's phenotypes alone
vary far less than real people (height and weight give their girths within 1 %); the
prior's draws give the 2-4 % real people show.

The body stands with its arms 15-50 degrees from the body and the legs 0-5 degrees apart
(thighs always clear), in painted clothes (a top, trousers or shorts or a skirt-length
bottom, sleeves of any length; tight clothing, as the body is the garment's surface) and a
skin tone, and is rendered from the front, back, left, right and one random side, each
with a random camera distance (the person fills 50-90 % of the picture's height),
height, focal length and a turn of up to 10 degrees, on a wall-and-floor background.
MediaPipe's BlazePose (`tryon.perceive.person`, the same finder real photos go through)
then gives each view's mask and keypoints: the training inputs carry the real mask
model's errors (soft edges, merged arms) because they come from it.

Stored per view: the mask cropped to a square around the person and resized to
`CROP` px (packed bits), the 33 keypoints in that crop (0-1) with visibility, the 3D
landmarks, the crop box, the camera, the true joints projected into the crop, whether
BlazePose found the person, and whether the finder's checks (`refusal`) accept the
picture and why not (kept apart, so the checks may change without making the data
again). Per sample: gender, age, stature, weight, the
Anny shape vector and every tape measurement of the fitted body (ground truth).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from tryon.body.fit import Measurements, fit_body
from tryon.body.pose import arm_pose, clear_thighs, leg_spread, posed_body
from tryon.body.prior import default_prior
from tryon.body.tape import TAPES
from tryon.dataset.bodies import BodyRanges, draw_measurements
from tryon.dataset.drapes import GENDER_CODE, shape_vector, split_of
from tryon.dataset.store import Manifest
from tryon.errors import TryonError

KIND = "bodies"
GENERATOR_VERSION = 1
VIEWS = ("front", "back", "left", "right", "random")
# camera azimuth from the front towards +X; "left": the camera sees the body's left side (+X)
VIEW_AZIMUTH = {"front": 0.0, "back": 180.0, "left": 90.0, "right": -90.0}
CROP = 128  # tryon.perceive.person.CROP: what the regression reads
TRUE_CROP = 64  # the rendered silhouette, kept coarser (to judge the finder's masks)
IMAGE_WH = (480, 640)
# what the prior draws and the fit is asked to meet (the rest follows Anny's shape)
DRAWN = ("chest_cm", "waist_navel_cm", "hip_cm", "neck_cm", "thigh_cm", "shoulder_width_cm", "arm_length_cm",
         "crotch_height_cm")
# true joints projected into each view (bone heads), for reprojection losses
JOINTS = ("upperarm01.L", "upperarm01.R", "lowerarm01.L", "lowerarm01.R", "wrist.L", "wrist.R", "upperleg01.L",
          "upperleg01.R", "lowerleg01.L", "lowerleg01.R", "foot.L", "foot.R", "neck01", "head", "spine03")
SKIN = ((0.96, 0.80, 0.69), (0.90, 0.70, 0.56), (0.78, 0.57, 0.42), (0.62, 0.42, 0.28), (0.44, 0.29, 0.19),
        (0.30, 0.20, 0.14))


@dataclass
class PhotoDatasetSpec:
    """`count` people, each photographed from every view in `views`."""

    count: int = 100
    seed: int = 0
    ranges: BodyRanges = field(default_factory=lambda: BodyRanges(bmi=(17.0, 40.0)))
    views: tuple[str, ...] = VIEWS
    clothing: str = "tight"   # painted on the body (loose garments: a later generator version)
    shard_size: int = 64
    train_fraction: float = 0.8
    val_fraction: float = 0.1

    def validate(self) -> None:
        if not 1 <= self.count <= 1_000_000:
            raise TryonError(f"--count {self.count}: give 1 to 1,000,000 people")
        if self.clothing != "tight":
            raise TryonError(f"clothing {self.clothing!r}: this generator paints tight clothing only")
        bad = [v for v in self.views if v not in VIEWS]
        if bad or not self.views:
            raise TryonError(f"views {list(self.views)}: use some of {', '.join(VIEWS)}")
        if not 1 <= self.shard_size <= 4096:
            raise TryonError(f"shard size {self.shard_size} is outside 1-4096 samples")

    def manifest(self, software_version: str) -> Manifest:
        self.validate()
        spec = {"views": list(self.views), "clothing": self.clothing, "crop_px": CROP, "true_crop_px": TRUE_CROP,
                "image_wh": list(IMAGE_WH), "drawn": list(DRAWN),
                "joints": list(JOINTS), "tapes": list(TAPES), "ranges": self.ranges.to_dict(),
                "finder": "mediapipe 0.10.14 BlazePose full (tryon.perceive.person)"}
        split = {"rule": "by person: train / val / test drawn per person from the seed", "train": self.train_fraction,
                 "val": self.val_fraction, "extrapolation_bmi": None}  # None: as JSON writes it back
        return Manifest(KIND, GENERATOR_VERSION, software_version, self.seed, self.count, self.shard_size, spec, split,
                        created=time.strftime("%Y-%m-%dT%H:%M:%S%z"))


@dataclass
class DrawnPerson:
    gender: str
    age: float
    height_cm: float
    weight_kg: float
    asked: dict[str, float]


def draw_person(seed: int, index: int, ranges: BodyRanges) -> DrawnPerson:
    """Sample `index`'s person: stature, BMI, age uniform; the rest from the ANSUR II prior."""
    gender, age, height, bmi = draw_measurements(seed, index, ranges)
    weight = round(bmi * (height / 100.0) ** 2, 2)
    rng = np.random.default_rng([seed, index, 1])
    drawn = default_prior().sample(gender, height, age, {"weight_kg": weight}, rng)
    return DrawnPerson(gender, age, height, weight, {k: round(drawn[k], 2) for k in DRAWN})


def _clothes_colours(body, rng: np.random.Generator) -> np.ndarray:
    """Per-vertex colours: skin, a top with sleeves of some length, a bottom of some
    length (tight clothing painted on the body)."""
    v, part, heads = body.vertices, body.part, body.heads
    skin = np.array(SKIN[int(rng.integers(len(SKIN)))])
    top, bottom = rng.uniform(0.05, 0.95, 3), rng.uniform(0.05, 0.9, 3)
    colours = np.tile(skin, (len(v), 1))
    neck_z = heads["neck01"][2] - 0.03
    waist_z = heads["spine03"][2] - rng.uniform(0.0, 0.12)
    torso = part == 0
    colours[torso & (v[:, 2] < neck_z) & (v[:, 2] >= waist_z)] = top
    colours[torso & (v[:, 2] < waist_z)] = bottom
    sleeve = rng.uniform(0.0, 1.0)  # fraction of shoulder-to-wrist covered
    for side, p in (("L", 1), ("R", 2)):
        sh, wr = heads[f"upperarm01.{side}"], heads[f"wrist.{side}"]
        t = ((v - sh) @ (wr - sh)) / max(float((wr - sh) @ (wr - sh)), 1e-9)
        colours[(part == p) & (t < sleeve)] = top
    hem = rng.uniform(0.0, 1.0)  # 0: trousers to the ankle, 1: shorts at the crotch
    for side, p in (("L", 3), ("R", 4)):
        hip, ankle = heads[f"upperleg01.{side}"], heads[f"foot.{side}"]
        t = ((v - hip) @ (ankle - hip)) / max(float((ankle - hip) @ (ankle - hip)), 1e-9)
        colours[(part == p) & (t < 1.0 - 0.75 * hem)] = bottom
    shoes = rng.uniform(0.0, 0.5, 3)
    colours[v[:, 2] < min(heads["foot.L"][2], heads["foot.R"][2]) + 0.02] = shoes
    return colours


def _background(rng: np.random.Generator, wh: tuple[int, int]) -> np.ndarray:
    """A wall over a floor, with a little sensor noise: [H,W,3] uint8."""
    w, h = wh
    wall, floor = rng.uniform(0.3, 0.95, 3), rng.uniform(0.15, 0.8, 3)
    horizon = int(h * rng.uniform(0.6, 0.85))
    img = np.empty((h, w, 3))
    img[:horizon] = wall
    img[horizon:] = floor
    img *= np.linspace(1.0, rng.uniform(0.75, 1.0), w)[None, :, None]
    img = img * 255 + rng.normal(0.0, 3.0, img.shape)
    return img.clip(0, 255).astype(np.uint8)


def _camera(body_v: np.ndarray, azimuth_deg: float, rng: np.random.Generator):
    """A camera at `azimuth_deg` (from the front, towards +X) at a distance that makes the
    person fill 50-90 % of the height, lens 35-55 degrees, eye 0.8-1.6 m high."""
    from tryon.render.offscreen import Camera

    lo, hi = body_v.min(0), body_v.max(0)
    centre = np.array([(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, (lo[2] + hi[2]) / 2])
    fov = rng.uniform(35.0, 55.0)
    fill = rng.uniform(0.5, 0.9)
    dist = (hi[2] - lo[2]) / fill / (2 * math.tan(math.radians(fov) / 2))
    a = math.radians(azimuth_deg)
    eye_z = lo[2] + rng.uniform(0.8, 1.6)
    eye = centre + np.array([dist * math.sin(a), -dist * math.cos(a), 0.0])
    eye[2] = eye_z
    target = centre + np.array([0.0, 0.0, rng.uniform(-0.05, 0.05) * (hi[2] - lo[2])])
    return Camera(eye=eye, target=target, fov_deg=fov)


def render_photo(body, colours: np.ndarray, azimuth: float, rng: np.random.Generator):
    """(the photo [H,W,3] uint8, its camera, the background's pixels [H,W] bool) of the
    posed, painted body from `azimuth`, with a random camera and wall."""
    from tryon.render.offscreen import RenderMesh, render_meshes

    w, h = IMAGE_WH
    cam = _camera(body.vertices, azimuth, rng)
    bg = _background(rng, IMAGE_WH)
    fg = render_meshes([RenderMesh(body.vertices, body.faces, vertex_colors=colours)], w, h, cam,
                       background=(1.0, 0.0, 1.0))
    key = (fg[..., 0] > 250) & (fg[..., 1] < 5) & (fg[..., 2] > 250)
    return np.where(key[..., None], bg, fg), cam, key


def photograph(shape, views: tuple[str, ...] = ("front", "left"), seed: int = 0) -> list[np.ndarray]:
    """Photos of a body as the photo datasets take them (arms 15-50 degrees out, painted
    tight clothes, a random camera per view): for tests, pictures and benches."""
    rng = np.random.default_rng(seed)
    R, _ = clear_thighs(shape, leg_spread(shape, arm_pose(shape, rng.uniform(15.0, 50.0)), rng.uniform(0.0, 5.0)))
    body = posed_body(shape, R)
    colours = _clothes_colours(body, rng)
    return [render_photo(body, colours, rng.uniform(0.0, 360.0) if v == "random" else
                         VIEW_AZIMUTH[v] + rng.uniform(-10.0, 10.0), rng)[0] for v in views]


def _view(body, colours, azimuth: float, rng: np.random.Generator, joints: np.ndarray) -> dict[str, np.ndarray]:
    from tryon.perceive.person import crop_box, crop_mask, detect_person, refusal

    w, h = IMAGE_WH
    photo, cam, key = render_photo(body, colours, azimuth, rng)
    out = {"azimuth_deg": np.float32(azimuth), "fov_deg": np.float32(cam.fov_deg),
           "eye": cam.eye.astype(np.float32), "target": cam.target.astype(np.float32)}
    true_mask = (~key).astype(np.float32)
    p = detect_person(photo, "render")
    if p is not None:
        mask, kp, vis, world, box = p.mask, p.keypoints, p.visibility, p.world, p.box
        why = refusal(p, (h, w))
    else:
        ys, xs = np.nonzero(true_mask)
        box = (int(xs.min()), int(ys.min()), int(xs.max()) + 1, int(ys.max()) + 1)
        mask, kp, vis, world, why = np.zeros((h, w)), np.zeros((33, 2)), np.zeros(33), np.zeros((33, 3)), "no person"
    crop = crop_box(box)
    x0, y0, side = crop
    out.update({"found": np.bool_(p is not None), "accepted": np.bool_(why is None),
                "refusal": np.asarray((why or "")[:120]), "crop": np.array(crop, np.float32),
                "mask_bits": np.packbits(crop_mask(mask, crop) > 0.5),
                "true_mask_bits": np.packbits(crop_mask(true_mask, crop, TRUE_CROP) > 0.5),
                "keypoints": ((kp - [x0, y0]) / side).astype(np.float16), "visibility": vis.astype(np.float16),
                "world": world.astype(np.float16),
                "joints_2d": ((cam.project(joints, w, h) - [x0, y0]) / side).astype(np.float32)})
    return out


def photo_unit(manifest: Manifest, shared: object, unit: int) -> dict[str, np.ndarray]:
    """One person photographed from every view of the manifest (a flat dict of arrays)."""
    t0 = time.perf_counter()
    spec = manifest.spec
    person = draw_person(manifest.seed, unit, BodyRanges.from_dict(spec["ranges"]))
    fit = fit_body(Measurements(height_cm=person.height_cm, weight_kg=person.weight_kg, gender=person.gender,
                                age=person.age, **person.asked))
    rng = np.random.default_rng([manifest.seed, unit, 2])
    shape = fit.shape
    arms, legs = rng.uniform(15.0, 50.0), rng.uniform(0.0, 5.0)
    R, extra = clear_thighs(shape, leg_spread(shape, arm_pose(shape, arms), legs))
    body = posed_body(shape, R)
    joints = np.stack([body.heads[j] for j in spec["joints"]])
    colours = _clothes_colours(body, rng)
    out: dict[str, np.ndarray] = {
        "gender": np.asarray(GENDER_CODE[person.gender]), "age": np.float32(person.age),
        "height_cm": np.float32(person.height_cm), "weight_kg": np.float32(person.weight_kg),
        "bmi": np.float32(person.weight_kg / (person.height_cm / 100) ** 2), "shape_params": shape_vector(fit.params),
        "asked": np.array([person.asked[k] for k in DRAWN], np.float32),
        "tapes_cm": np.array([fit.achieved[f"{t}_cm"] for t in spec["tapes"]], np.float32),
        "arm_angle_deg": np.float32(arms), "leg_spread_deg": np.float32(legs + extra),
        "joints_3d": joints.astype(np.float32),
        "split": np.asarray(split_of(manifest, unit, 0.0)),
    }
    views = []
    for v in spec["views"]:
        azimuth = rng.uniform(0.0, 360.0) if v == "random" else VIEW_AZIMUTH[v] + rng.uniform(-10.0, 10.0)
        views.append(_view(body, colours, azimuth, rng, joints))
    for k in views[0]:
        out[f"view_{k}"] = np.stack([v[k] for v in views])
    out["ok"] = np.asarray(bool(out["view_found"].any()))
    out["wall_s"] = np.asarray(time.perf_counter() - t0)
    return out


def make_photo_dataset(spec: PhotoDatasetSpec, out, workers: int = 1, ray_address: str | None = None,
                       force: bool = False, progress: bool = True, limit: int | None = None):
    from tryon.dataset.generate import open_dataset, run_generator
    from tryon.dataset.store import software_version

    store = open_dataset(out, spec.manifest(software_version()), force=force)
    report = run_generator(store, lambda m, f: None, photo_unit, workers=workers, ray_address=ray_address,
                           progress=progress, limit=limit)
    return store, report
