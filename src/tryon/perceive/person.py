"""The person in a photo: mask and 33 keypoints from MediaPipe's BlazePose (full model,
`mediapipe==0.10.14`, bundled in its wheel, runs offline), checked to be one whole
standing person large enough to measure.

A photo is refused with one line naming it when no person is found, when the head or the
feet are outside the frame, when the person is too small, or when they are not standing
(legs bent or spread, torso leaning). BlazePose finds one person per call; for several
people the found one is painted out and the photo searched again, and the largest whole
one is used (`PersonInPhoto.note` says so).
"""

from __future__ import annotations

import os
import warnings
from dataclasses import dataclass, field

import numpy as np

from tryon.errors import TryonError
from tryon.perceive.images import load_photo

# BlazePose's 33 landmarks, in its order
KEYPOINTS = (
    "nose", "left_eye_inner", "left_eye", "left_eye_outer", "right_eye_inner", "right_eye", "right_eye_outer",
    "left_ear", "right_ear", "mouth_left", "mouth_right", "left_shoulder", "right_shoulder", "left_elbow",
    "right_elbow", "left_wrist", "right_wrist", "left_pinky", "right_pinky", "left_index", "right_index",
    "left_thumb", "right_thumb", "left_hip", "right_hip", "left_knee", "right_knee", "left_ankle", "right_ankle",
    "left_heel", "right_heel", "left_foot_index", "right_foot_index",
)
K = {name: i for i, name in enumerate(KEYPOINTS)}
HEAD = [K[n] for n in ("nose", "left_eye", "right_eye", "left_ear", "right_ear")]
FEET = [K[n] for n in ("left_ankle", "right_ankle", "left_heel", "right_heel", "left_foot_index", "right_foot_index")]
SKELETON = ((11, 12), (11, 13), (13, 15), (12, 14), (14, 16), (11, 23), (12, 24), (23, 24), (23, 25), (25, 27),
            (27, 29), (29, 31), (27, 31), (24, 26), (26, 28), (28, 30), (30, 32), (28, 32), (7, 2), (2, 0), (0, 5),
            (5, 8))

WORK_SIDE = 1024          # px: photos are searched at most this large (BlazePose sees 256 px)
MIN_PERSON_PX = 240       # px of the original photo, head to heels
MIN_PERSON_FRACTION = 0.3  # of the photo's height
MIN_VISIBILITY = 0.5
MAX_TORSO_LEAN_DEG = 30.0
MAX_LEG_LEAN_DEG = 25.0    # hip-to-ankle line from the vertical, each leg
MIN_KNEE_DEG = 130.0      # hip-knee-ankle, 3D landmarks (180: straight; straight legs of renders read 139 up)
MAX_STRIDE_M = 0.65       # ankle to ankle, 3D landmarks: beyond this the person is walking
MAX_PEOPLE = 4
MASK_LEVEL = 0.5
CROP = 128  # px: the square crop around the person that the body-from-photos regression reads


@dataclass
class PersonInPhoto:
    """One person found in a photo, in the coordinates of `image` (the photo scaled by
    `scale`, at most WORK_SIDE px): mask [H,W] in 0-1, keypoints [33,2] px (x right, y
    down), visibility [33], world [33,3] (BlazePose's metric 3D landmarks, hip-centred)."""

    name: str
    image: np.ndarray
    scale: float
    mask: np.ndarray
    keypoints: np.ndarray
    visibility: np.ndarray
    world: np.ndarray
    people_found: int = 1
    notes: list[str] = field(default_factory=list)

    @property
    def box(self) -> tuple[int, int, int, int]:
        """(x0, y0, x1, y1) px of the mask, or of the keypoints if the mask is empty."""
        ys, xs = np.nonzero(self.mask > MASK_LEVEL)
        if len(ys) == 0:
            lo, hi = self.keypoints.min(0), self.keypoints.max(0)
            return int(lo[0]), int(lo[1]), int(hi[0]), int(hi[1])
        return int(xs.min()), int(ys.min()), int(xs.max()) + 1, int(ys.max()) + 1

    @property
    def height_px(self) -> float:
        """Head top (mask) to the lower heel, in pixels of the original photo."""
        top = self.box[1]
        bottom = max(self.keypoints[FEET, 1].max(), self.box[3])
        return float(bottom - top) / self.scale


class PersonNotFound(TryonError):
    """A photo does not show one whole standing person that can be measured."""


_POSE = None


def _pose_model():
    """BlazePose full (model_complexity=1: the only one in the wheel; 0 and 2 download)."""
    global _POSE
    if _POSE is None:
        os.environ.setdefault("GLOG_minloglevel", "2")  # mediapipe's C++ start-up chatter
        try:
            import mediapipe as mp
        except ImportError as exc:
            raise TryonError(f"finding people in photos needs mediapipe 0.10.14 and OpenCV's system libraries "
                             f"({exc}): pip install mediapipe==0.10.14 protobuf==4.25.9; apt-get install libgl1 "
                             f"libglib2.0-0") from exc
        _POSE = mp.solutions.pose.Pose(static_image_mode=True, model_complexity=1, enable_segmentation=True,
                                       min_detection_confidence=0.5)
    return _POSE


def _detect(image: np.ndarray, name: str, scale: float) -> PersonInPhoto | None:
    model = _pose_model()
    with warnings.catch_warnings():  # mediapipe 0.10.14 reads its results through a deprecated protobuf call
        warnings.simplefilter("ignore", UserWarning)
        res = model.process(image)
    if res.pose_landmarks is None:
        return None
    h, w = image.shape[:2]
    lm = res.pose_landmarks.landmark
    kp = np.array([[p.x * w, p.y * h] for p in lm])
    vis = np.array([p.visibility for p in lm])
    world = np.array([[p.x, p.y, p.z] for p in res.pose_world_landmarks.landmark])
    seg = res.segmentation_mask
    mask = np.zeros((h, w), np.float32) if seg is None else np.asarray(seg, np.float32)
    return PersonInPhoto(name, image, scale, mask, kp, vis, world)


def _angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    c = float(np.dot(a, b) / max(np.linalg.norm(a) * np.linalg.norm(b), 1e-12))
    return float(np.degrees(np.arccos(np.clip(c, -1.0, 1.0))))


def refusal(p: PersonInPhoto, photo_hw: tuple[int, int]) -> str | None:
    """Why this person cannot be measured, or None."""
    h, w = p.image.shape[:2]
    kp, vis = p.keypoints, p.visibility
    inside = (kp[:, 0] >= 0) & (kp[:, 0] <= w - 1) & (kp[:, 1] >= 0) & (kp[:, 1] <= h - 1)
    m = p.mask > MASK_LEVEL
    # BlazePose places points beyond the frame where it guesses them; a heel hidden behind
    # the other foot is inside the frame but not visible, which is no reason to refuse
    head_at_top = m[0].mean() > 0.01 and kp[HEAD, 1].min() < 0.05 * h
    if not inside[HEAD].all() or vis[HEAD].max() < MIN_VISIBILITY or head_at_top:
        return "the head is outside the picture (cut off); photograph the whole person, head to feet"
    if not inside[FEET].all() or vis[FEET].max() < MIN_VISIBILITY:  # (the mask's bottom row is no test: shadows bleed)
        return "the feet are outside the picture (cut off); photograph the whole person, head to feet"
    if p.height_px < MIN_PERSON_PX or p.height_px < MIN_PERSON_FRACTION * photo_hw[0]:
        return (f"the person is too small ({p.height_px:.0f} px of a {photo_hw[0]} px tall picture; at least "
                f"{MIN_PERSON_PX} px and {MIN_PERSON_FRACTION:.0%} of the height): step closer or crop")
    up = np.array([0.0, -1.0])
    mid = lambda a, b: (kp[K[a]] + kp[K[b]]) / 2  # noqa: E731
    shoulders, hips = mid("left_shoulder", "right_shoulder"), mid("left_hip", "right_hip")
    knees, ankles = mid("left_knee", "right_knee"), mid("left_ankle", "right_ankle")
    if not (shoulders[1] < hips[1] < knees[1] < ankles[1]):
        return "the person is not standing upright (shoulders, hips, knees and ankles are not one above the other)"
    lean = _angle_deg(shoulders - hips, up)
    if lean > MAX_TORSO_LEAN_DEG:
        return f"the person is not standing upright (torso leans {lean:.0f} degrees); stand straight, facing the camera"
    hips_dx = kp[K["left_hip"], 0] - kp[K["right_hip"], 0]
    ankles_dx = kp[K["left_ankle"], 0] - kp[K["right_ankle"], 0]
    if abs(hips_dx) > 0.25 * np.linalg.norm(shoulders - hips) and hips_dx * ankles_dx < 0 \
            and abs(ankles_dx) > 0.02 * h:
        return "the person is not standing (the legs cross, as in a step); stand still with the feet apart"
    stride = float(np.linalg.norm(p.world[K["left_ankle"]] - p.world[K["right_ankle"]]))
    if stride > MAX_STRIDE_M:
        return f"the person is not standing (the feet are {100 * stride:.0f} cm apart, as in a step); stand still"
    for side in ("left", "right"):
        leg = _angle_deg(kp[K[f"{side}_hip"]] - kp[K[f"{side}_ankle"]], up)
        wv = p.world
        knee = _angle_deg(wv[K[f"{side}_hip"]] - wv[K[f"{side}_knee"]], wv[K[f"{side}_ankle"]] - wv[K[f"{side}_knee"]])
        if leg > MAX_LEG_LEAN_DEG or knee < MIN_KNEE_DEG:
            return (f"the person is not standing (the {side} leg is {'bent' if knee < MIN_KNEE_DEG else 'spread'}: "
                    f"knee {knee:.0f} degrees, {leg:.0f} from vertical); stand straight with the legs slightly apart")
    return None


def _paint_out(image: np.ndarray, p: PersonInPhoto) -> np.ndarray:
    """The photo with this person covered in grey (mask grown by a few pixels, and the
    keypoints' box if the mask is thin), so the next search finds someone else."""
    from scipy.ndimage import binary_dilation

    out = image.copy()
    m = binary_dilation(p.mask > 0.2, iterations=max(2, image.shape[0] // 100))
    lo, hi = np.floor(p.keypoints.min(0)).astype(int), np.ceil(p.keypoints.max(0)).astype(int)
    if m.sum() < 0.25 * max(1, (hi - lo).prod()):
        m[max(lo[1], 0):max(hi[1], 0), max(lo[0], 0):max(hi[0], 0)] = True
    out[m] = 127
    return out


def _overlaps(a: PersonInPhoto, b: PersonInPhoto) -> bool:
    ax0, ay0, ax1, ay1 = a.box
    bx0, by0, bx1, by1 = b.box
    iw, ih = max(0, min(ax1, bx1) - max(ax0, bx0)), max(0, min(ay1, by1) - max(ay0, by0))
    small = min((ax1 - ax0) * (ay1 - ay0), (bx1 - bx0) * (by1 - by0))
    return iw * ih > 0.5 * max(small, 1)


def working_image(photo: np.ndarray) -> tuple[np.ndarray, float]:
    """The photo scaled to at most WORK_SIDE px, and the scale."""
    from PIL import Image

    H, W = photo.shape[:2]
    scale = min(1.0, WORK_SIDE / max(H, W))
    if scale == 1.0:
        return photo, 1.0
    return np.asarray(Image.fromarray(photo).resize((round(W * scale), round(H * scale)), Image.BILINEAR)), scale


def detect_person(photo: np.ndarray, name: str = "photo") -> PersonInPhoto | None:
    """BlazePose's one most prominent person in the photo, unchecked (None if none)."""
    image, scale = working_image(photo)
    return _detect(image, name, scale)


def people_in_photo(photo: np.ndarray, name: str = "photo") -> list[PersonInPhoto]:
    """Everyone BlazePose finds in the photo (at most MAX_PEOPLE), unchecked: each found
    person is painted out and the photo searched again."""
    image, scale = working_image(photo)
    found: list[PersonInPhoto] = []
    search = image
    for _ in range(MAX_PEOPLE):
        p = _detect(search, name, scale)
        if p is None or any(_overlaps(p, q) for q in found):
            break
        p.image = image
        found.append(p)
        search = _paint_out(search, p)
    return found


def find_person(photo: np.ndarray, name: str = "photo") -> PersonInPhoto:
    """The largest whole standing person in an RGB photo [H,W,3] uint8; PersonNotFound
    (naming `name`) if there is none."""
    H, W = photo.shape[:2]
    found = people_in_photo(photo, name)
    if not found:
        raise PersonNotFound(f"{name}: no person found; use a photo of one whole standing person")
    reasons = [refusal(p, (H, W)) for p in found]
    whole = sorted((p for p, r in zip(found, reasons) if r is None), key=lambda p: -p.height_px)
    if not whole:
        largest = max(range(len(found)), key=lambda i: found[i].height_px)
        several = f" ({len(found)} people found, none whole and standing)" if len(found) > 1 else ""
        raise PersonNotFound(f"{name}: {reasons[largest]}{several}")
    best = whole[0]
    best.people_found = len(found)
    if len(found) > 1:
        best.notes.append(f"{len(found)} people in {name}: the largest whole standing one is used")
    return best


def find_person_in_file(path: str | os.PathLike[str]) -> PersonInPhoto:
    """`find_person` on a photo file (errors name the file)."""
    return find_person(load_photo(path), str(path))


def crop_box(box: tuple[int, int, int, int], margin: float = 0.1) -> tuple[float, float, float]:
    """(x0, y0, side) of the square around a person's box, `margin` of its height added."""
    x0, y0, x1, y1 = box
    side = max(x1 - x0, y1 - y0) * (1 + 2 * margin)
    cx, cy = (x0 + x1) / 2, (y0 + y1) / 2
    return cx - side / 2, cy - side / 2, side


def crop_mask(mask: np.ndarray, crop: tuple[float, float, float], size: int = CROP) -> np.ndarray:
    """The mask [H,W] (0-1) inside the square crop, resampled to size x size."""
    from PIL import Image

    x0, y0, side = crop
    img = Image.fromarray((np.clip(mask, 0, 1) * 255).astype(np.uint8))
    out = img.transform((size, size), Image.EXTENT, (x0, y0, x0 + side, y0 + side), Image.BILINEAR, fillcolor=0)
    return np.asarray(out, dtype=np.float32) / 255.0


def person_tile(image: np.ndarray, box, height: int, aspect: float | None = None, pad: float = 0.1) -> np.ndarray:
    """The person in `image` (their `box` x0, y0, x1, y1 in its pixels), with `pad` of the
    box's height above, below and (without `aspect`) beside them, centred, as a tile
    `height` pixels high: `aspect` (width / height) wide, or as wide as the padded box."""
    from PIL import Image

    x0, y0, x1, y1 = (float(v) for v in box)
    margin = pad * (y1 - y0)
    side = max(8.0, y1 - y0 + 2 * margin)
    wide = side * aspect if aspect else x1 - x0 + 2 * margin
    cx = (x0 + x1) / 2
    crop = Image.fromarray(image).crop((int(cx - wide / 2), int(y0 - margin), int(cx + wide / 2), int(y0 - margin + side)))
    width = int(round(height * aspect)) if aspect else max(1, int(crop.width * height / crop.height))
    return np.asarray(crop.resize((width, height)))


@dataclass
class PersonCrop:
    """What the body-from-photos regression reads of one person: the mask in the square
    crop around them (bool [CROP,CROP]), the 33 keypoints in crop units (0-1) with
    visibility ([33,3]), and the crop (x0, y0, side) in the working image's pixels."""

    mask: np.ndarray
    keypoints: np.ndarray
    crop: tuple[float, float, float]


def person_crop(p: PersonInPhoto, size: int = CROP) -> PersonCrop:
    """The crop of a found person, exactly as the photo datasets store it."""
    crop = crop_box(p.box)
    x0, y0, side = crop
    kp = np.concatenate([(p.keypoints - [x0, y0]) / side, p.visibility[:, None]], 1)
    return PersonCrop(crop_mask(p.mask, crop, size) > 0.5, kp.astype(np.float32), crop)


def overlay(p: PersonInPhoto) -> np.ndarray:
    """The photo with the mask tinted and the keypoint skeleton drawn (RGB uint8)."""
    from PIL import Image, ImageDraw

    img = p.image.astype(np.float32)
    tint = np.array([40.0, 170.0, 255.0])
    a = 0.45 * np.clip(p.mask, 0, 1)[..., None]
    img = Image.fromarray((img * (1 - a) + tint * a).clip(0, 255).astype(np.uint8))
    draw = ImageDraw.Draw(img)
    r = max(2, img.height // 150)
    for i, j in SKELETON:
        draw.line([tuple(p.keypoints[i]), tuple(p.keypoints[j])], fill=(255, 200, 0), width=max(1, r // 2 + 1))
    for (x, y), v in zip(p.keypoints, p.visibility):
        colour = (230, 30, 30) if v >= MIN_VISIBILITY else (120, 120, 120)
        draw.ellipse([x - r, y - r, x + r, y + r], fill=colour)
    return np.asarray(img)
