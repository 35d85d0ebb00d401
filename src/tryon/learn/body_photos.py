"""The body from photos: a multi-view, multi-stage recurrent regression (Liang's
dissertation, ch.2) over what the person finder sees in each view.

Each view is encoded from its mask crop (a small CNN), its 33 keypoints (an MLP) and the
silhouette's width profile (`silhouette_profile`: the width of the body's own run of mask
pixels at levels set by the shoulders, hips and knees, over the person's height in the
crop; an MLP) into one feature. The profile is what a tailor reads off a photo; a CNN
trained from scratch on a thousand people did not find it by itself (no better than
stature and weight after seven epochs, where a ridge regression on the profile already
cut the girths' error by nearly half: 1.56 % against 2.88 %). One shared body state (every tape measurement, as a residual from what
stature, weight and gender predict) and one camera per view (yaw as cos / sin, scale,
offset) start at zero; in each of three stages a regression block takes every view in turn
and adds a correction to the body state and to that view's camera from that view's
feature. Any number of views goes through the same network: training drops views at
random. Heads read the final state: a log-spread per measurement (trained by the
Gaussian likelihood, the uncertainty reported), Anny's shape vector, and the 3D joints,
which each view's camera projects onto that view's crop (the reprojection loss).

The baseline the residuals are taken from (`HeightWeightBaseline`) is a least-squares fit
of every log measurement on log stature, log weight and gender over the training people:
the body from height and weight alone, which the regression has to beat.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch
from torch import nn

from tryon.errors import TryonError

KEYPOINTS = 33
CONDITIONS = 4  # stature, weight, gender, whether the weight was given
PROFILE = 48  # silhouette widths per view, from above the shoulders to the knees
# BlazePose's shoulders, hips and knees (left, right): the profile's levels follow them
_SHOULDERS, _HIPS, _KNEES = (11, 12), (23, 24), (25, 26)
CAMERA = 5  # cos yaw, sin yaw, scale, x offset, y offset (weak perspective on the crop)


@dataclass
class RegressorConfig:
    crop: int = 128
    cnn_side: int = 64  # the CNN sees the mask pooled to this (the profile keeps the crop's detail)
    feature: int = 256
    hidden: int = 512
    stages: int = 3
    measurements: int = 16
    shape: int = 32
    joints: int = 15
    profile: int = PROFILE
    conditions: int = CONDITIONS

    def to_dict(self) -> dict:
        return asdict(self)


def _baseline_features(height_cm: np.ndarray, weight_kg: np.ndarray, gender: np.ndarray) -> np.ndarray:
    h = np.log(np.asarray(height_cm, np.float64) / 170.0)
    w = np.log(np.asarray(weight_kg, np.float64) / 70.0)
    g = np.asarray(gender, np.float64)
    return np.stack([np.ones_like(h), h, w, g, g * h, g * w], -1)


@dataclass
class HeightWeightBaseline:
    """log measurement = features(stature, weight, gender) @ coef, residual spread `sd`."""

    coef: np.ndarray   # [6, M]
    sd: np.ndarray     # [M]

    @classmethod
    def fit(cls, height_cm, weight_kg, gender, tapes_cm: np.ndarray) -> "HeightWeightBaseline":
        x = _baseline_features(height_cm, weight_kg, gender)
        y = np.log(tapes_cm)
        coef, *_ = np.linalg.lstsq(x, y, rcond=None)
        return cls(coef, np.maximum((y - x @ coef).std(0), 1e-4))

    def log_mean(self, height_cm, weight_kg, gender) -> np.ndarray:
        return _baseline_features(height_cm, weight_kg, gender) @ self.coef

    def residual(self, height_cm, weight_kg, gender, tapes_cm) -> np.ndarray:
        """The standardised residual the network predicts."""
        return (np.log(tapes_cm) - self.log_mean(height_cm, weight_kg, gender)) / self.sd

    def measurements(self, height_cm, weight_kg, gender, residual: np.ndarray) -> np.ndarray:
        return np.exp(self.log_mean(height_cm, weight_kg, gender) + residual * self.sd)


def _run_widths(m: np.ndarray, point: np.ndarray) -> np.ndarray:
    """Width (px) of the run of mask pixels containing each point, averaged over the
    point's row and the rows above and below: m [M,C,C] bool, point [M,L,2] px -> [M,L]."""
    C = m.shape[-1]
    x = np.clip(np.rint(point[..., 0]), 0, C - 1).astype(int)
    idx = np.arange(C)
    widths = np.zeros(x.shape)
    for dy in (-1, 0, 1):
        y = np.clip(np.rint(point[..., 1]).astype(int) + dy, 0, C - 1)
        row = m[np.arange(len(m))[:, None], y]                                # [M, L, C]
        gap = ~row
        left = np.where(gap & (idx < x[..., None]), idx, -1).max(-1)
        right = np.where(gap & (idx > x[..., None]), idx, C).min(-1)
        on = np.take_along_axis(row, x[..., None], -1)[..., 0]
        widths += np.where(on, right - left - 1, 0)
    return widths / 3.0


def silhouette_profile(masks: np.ndarray, keypoints: np.ndarray, levels: int = PROFILE) -> np.ndarray:
    """Widths of the body's silhouette at `levels` heights, over the mask's height:
    masks [..., C, C] (0/1), keypoints [..., 33, >=2] in crop units -> [..., levels] float32.

    Three quarters of the levels run down the torso, from a quarter above the shoulders to
    the hips, on the line through the shoulders' and hips' midpoints; the rest run down
    the legs from the hips to the knees, each level the mean of the left and the right
    leg's run (a side view sees both legs as one). Each width is the run of mask pixels
    containing the line, averaged over three rows (a crop's pixel is 1-3 % of a torso's
    width). Arms held apart from the torso are not counted; an arm touching it is, which
    the network learns to read."""
    masks = np.asarray(masks) > 0.5
    lead = masks.shape[:-2]
    C = masks.shape[-1]
    m = masks.reshape(-1, C, C)
    kp = np.asarray(keypoints, np.float64).reshape(-1, KEYPOINTS, keypoints.shape[-1])[..., :2] * C
    sh, hp = kp[:, list(_SHOULDERS)].mean(1), kp[:, list(_HIPS)].mean(1)
    torso_levels = (3 * levels) // 4
    f = np.linspace(-0.25, 1.0, torso_levels)[None, :, None]
    torso = _run_widths(m, sh[:, None] + (hp - sh)[:, None] * f)
    g = np.linspace(0.0, 1.0, levels - torso_levels + 1)[1:][None, :, None]
    legs = [_run_widths(m, kp[:, h][:, None] + (kp[:, k] - kp[:, h])[:, None] * g) for h, k in zip(_HIPS, _KNEES)]
    rows_any = m.any(2)
    top = rows_any.argmax(1)
    bottom = C - rows_any[:, ::-1].argmax(1)
    height = np.maximum(bottom - top, 1).astype(np.float64)
    out = np.concatenate([torso, 0.5 * (legs[0] + legs[1])], 1) / height[:, None]
    out[~rows_any.any(1)] = 0.0
    return out.reshape(*lead, levels).astype(np.float32)


def condition(height_cm, weight_kg, gender, weight_given=True) -> np.ndarray:
    """The network's person inputs [N,4]: stature, weight (normalised), gender, and 1 if the
    weight is the person's own, 0 if it is `WeightModel.from_height`'s guess."""
    h = np.asarray(height_cm, np.float64)
    given = np.broadcast_to(np.asarray(weight_given, np.float64), h.shape)
    return np.stack([(h - 170.0) / 10.0, (np.asarray(weight_kg) - 75.0) / 15.0, np.asarray(gender, np.float64),
                     given], -1).astype(np.float32)


# girths that tell the weight when the shopper does not give it (with stature and gender)
WEIGHT_TAPES = ("chest", "waist_navel", "hip", "thigh", "neck")


@dataclass
class WeightModel:
    """Log weight by least squares over the training people: from stature and gender
    (the guess the network starts from when no weight is given), and from stature, gender
    and the girths `WEIGHT_TAPES` (the weight the body is fitted to, from the girths the
    photos gave)."""

    coef_height: np.ndarray   # [4] on 1, log stature, gender, gender * log stature
    coef_tapes: np.ndarray    # [4 + len(WEIGHT_TAPES)] on those and the log girths
    sd_from_girths: float     # residual spread of log weight from the girths (training people)

    @staticmethod
    def _x(height_cm, gender) -> np.ndarray:
        h = np.log(np.atleast_1d(np.asarray(height_cm, np.float64)) / 170.0)
        g = np.broadcast_to(np.asarray(gender, np.float64), h.shape)
        return np.stack([np.ones_like(h), h, g, g * h], -1)

    @classmethod
    def fit(cls, height_cm, gender, weight_kg, girths_cm: np.ndarray) -> "WeightModel":
        """`girths_cm` [N, len(WEIGHT_TAPES)]."""
        x = cls._x(height_cm, gender)
        y = np.log(np.asarray(weight_kg, np.float64))
        a, *_ = np.linalg.lstsq(x, y, rcond=None)
        xg = np.concatenate([x, np.log(girths_cm)], 1)
        b, *_ = np.linalg.lstsq(xg, y, rcond=None)
        return cls(a, b, float(np.std(y - xg @ b)))

    def from_height(self, height_cm, gender) -> np.ndarray:
        return np.exp(self._x(height_cm, gender) @ self.coef_height)

    def from_girths(self, height_cm, gender, girths_cm: np.ndarray) -> np.ndarray:
        x = np.concatenate([self._x(height_cm, gender), np.log(np.atleast_2d(girths_cm))], 1)
        return np.exp(x @ self.coef_tapes)


class ViewEncoder(nn.Module):
    """A view's mask crop [B,1,C,C], keypoints [B,33,3] (x, y in the crop, visibility) and
    silhouette profile [B,P] to one feature [B,F]."""

    def __init__(self, cfg: RegressorConfig):
        super().__init__()
        chans = (1, 16, 32, 64, 96)
        layers: list[nn.Module] = []
        for a, b in zip(chans[:-1], chans[1:]):
            layers += [nn.Conv2d(a, b, 3, stride=2, padding=1), nn.GroupNorm(4, b), nn.ReLU()]
        self.cnn = nn.Sequential(*layers)
        self.pool = max(1, cfg.crop // cfg.cnn_side)
        side = cfg.crop // self.pool // 16
        self.mask_fc = nn.Linear(chans[-1] * side * side, cfg.feature)
        self.kp = nn.Sequential(nn.Linear(KEYPOINTS * 3, 256), nn.ReLU(), nn.Linear(256, cfg.feature))
        self.profile = nn.Sequential(nn.Linear(cfg.profile, 256), nn.ReLU(), nn.Linear(256, cfg.feature))
        # the profile's mean and spread over the training views (set by `standardise_profile`):
        # people differ by a few percent of a width, which unscaled inputs would drown
        self.register_buffer("profile_mean", torch.zeros(cfg.profile))
        self.register_buffer("profile_sd", torch.ones(cfg.profile))
        self.mix = nn.Sequential(nn.ReLU(), nn.Linear(3 * cfg.feature, cfg.feature), nn.ReLU())

    def standardise_profile(self, profiles: np.ndarray) -> None:
        """Set the profile's scaling from the training views' profiles [N,P]."""
        self.profile_mean.copy_(torch.from_numpy(profiles.mean(0).astype(np.float32)))
        self.profile_sd.copy_(torch.from_numpy(profiles.std(0).astype(np.float32) + 1e-3))

    def forward(self, mask: torch.Tensor, keypoints: torch.Tensor, profile: torch.Tensor) -> torch.Tensor:
        if self.pool > 1:
            mask = nn.functional.avg_pool2d(mask, self.pool)
        m = self.mask_fc(self.cnn(mask).flatten(1))
        k = self.kp(keypoints.flatten(1))
        p = self.profile((profile - self.profile_mean) / self.profile_sd)
        return self.mix(torch.cat([m, k, p], 1))


class BodyFromViews(nn.Module):
    """The multi-view, multi-stage recurrent regression; see the module docstring."""

    def __init__(self, cfg: RegressorConfig):
        super().__init__()
        self.cfg = cfg
        self.encoder = ViewEncoder(cfg)
        state = cfg.measurements + CAMERA + cfg.conditions
        self.blocks = nn.ModuleList([
            nn.Sequential(nn.Linear(cfg.feature + state, cfg.hidden), nn.ReLU(), nn.Linear(cfg.hidden, cfg.hidden),
                          nn.ReLU(), nn.Linear(cfg.hidden, cfg.measurements + CAMERA))
            for _ in range(cfg.stages)])
        head_in = cfg.measurements + cfg.conditions
        self.log_sd = nn.Sequential(nn.Linear(head_in + cfg.feature, 128), nn.ReLU(), nn.Linear(128, cfg.measurements))
        self.shape = nn.Sequential(nn.Linear(head_in, 128), nn.ReLU(), nn.Linear(128, cfg.shape))
        self.joints = nn.Sequential(nn.Linear(head_in, 128), nn.ReLU(), nn.Linear(128, cfg.joints * 3))

    def forward(self, mask: torch.Tensor, keypoints: torch.Tensor, profile: torch.Tensor, present: torch.Tensor,
                cond: torch.Tensor) -> dict[str, torch.Tensor]:
        """mask [B,V,1,C,C], keypoints [B,V,33,3], profile [B,V,P], present [B,V] (0/1), cond [B,4]
        (`condition`)."""
        B, V = present.shape
        feats = self.encoder(mask.flatten(0, 1), keypoints.flatten(0, 1), profile.flatten(0, 1)).view(B, V, -1)
        theta = torch.zeros(B, self.cfg.measurements, dtype=feats.dtype)
        cam = torch.zeros(B, V, CAMERA, dtype=feats.dtype)
        cam[..., 0] = 1.0
        cam[..., 2] = 1.0
        for block in self.blocks:
            for v in range(V):
                on = present[:, v:v + 1]
                d = block(torch.cat([feats[:, v], theta, cam[:, v], cond], 1))
                theta = theta + on * d[:, :self.cfg.measurements]
                cam = cam.clone()
                cam[:, v] = cam[:, v] + on * d[:, self.cfg.measurements:]
        pooled = (feats * present[..., None]).sum(1) / present.sum(1, keepdim=True).clamp(min=1.0)
        state = torch.cat([theta, cond], 1)
        return {"residual": theta, "log_sd": self.log_sd(torch.cat([state, pooled], 1)), "camera": cam,
                "shape": self.shape(state), "joints": self.joints(state).view(B, self.cfg.joints, 3)}


def project(joints: torch.Tensor, camera: torch.Tensor) -> torch.Tensor:
    """Weak-perspective projection of body-frame joints [B,J,3] (metres over stature,
    pelvis-centred, z up) by each view's camera [B,V,5] into its crop: [B,V,J,2]."""
    c, s = camera[..., 0:1], camera[..., 1:2]
    norm = torch.sqrt(c * c + s * s).clamp(min=1e-6)
    c, s = c / norm, s / norm
    x, y, z = joints[:, None, :, 0], joints[:, None, :, 1], joints[:, None, :, 2]
    u = c * x + s * y   # the camera's right after turning the body by the yaw
    scale, ox, oy = camera[..., 2:3], camera[..., 3:4], camera[..., 4:5]
    return torch.stack([0.5 + ox + 0.8 * scale * u, 0.5 + oy - 0.8 * scale * z], -1)


def unpack_masks(bits: np.ndarray, crop: int) -> np.ndarray:
    """Packed mask bits [..., crop*crop/8] to float32 [..., 1, crop, crop]."""
    out = np.unpackbits(bits, axis=-1).reshape(*bits.shape[:-1], crop, crop)
    return out[..., None, :, :].astype(np.float32)


def body_frame_joints(joints_3d: np.ndarray, height_cm: np.ndarray, names: list[str]) -> np.ndarray:
    """World joints [N,J,3] as the network predicts them: centred on the hip joints (on
    all joints if the hips are not among `names`), in units of stature."""
    hips = [i for i, n in enumerate(names) if n.startswith("upperleg01.")] or list(range(len(names)))
    centre = joints_3d[:, hips].mean(1, keepdims=True)
    return ((joints_3d - centre) / (np.asarray(height_cm)[:, None, None] / 100.0)).astype(np.float32)


def check_views(n: int) -> None:
    if not 1 <= n <= 8:
        raise TryonError(f"the body from photos takes 1 to 8 views, got {n}")


def save_model(path: str | Path, net: BodyFromViews, baseline: HeightWeightBaseline, weight: WeightModel,
               card: dict) -> Path:
    """The model as one .npz (weights, baseline, config and card as JSON; no pickle)."""
    from tryon.io.atomic import atomic_write

    arrays = {f"w/{k}": v.detach().numpy() for k, v in net.state_dict().items()}
    arrays.update({"baseline_coef": baseline.coef, "baseline_sd": baseline.sd,
                   "weight_coef_height": weight.coef_height, "weight_coef_tapes": weight.coef_tapes,
                   "weight_sd_from_girths": np.float64(weight.sd_from_girths),
                   "config": np.asarray(json.dumps(net.cfg.to_dict())), "card": np.asarray(json.dumps(card))})
    with atomic_write(path, "wb") as fh:
        np.savez_compressed(fh, **arrays)
    return Path(path)


@dataclass
class PhotoModel:
    """A trained body-from-photos model: the network, the baseline its residuals are
    taken from, the weight model, and its card (tape names, shape normalisation, metrics)."""

    net: BodyFromViews
    baseline: HeightWeightBaseline
    weight: WeightModel
    card: dict

    @property
    def tapes(self) -> list[str]:
        return list(self.card["tapes"])


def load_model(path: str | Path) -> PhotoModel:
    from tryon.io.npz import read_npz

    z = read_npz(Path(path), "body-from-photos model")
    try:
        cfg = RegressorConfig(**json.loads(str(z["config"])))
        net = BodyFromViews(cfg)
        net.load_state_dict({k[2:]: torch.from_numpy(np.asarray(v)) for k, v in z.items() if k.startswith("w/")})
        baseline = HeightWeightBaseline(np.asarray(z["baseline_coef"]), np.asarray(z["baseline_sd"]))
        weight = WeightModel(np.asarray(z["weight_coef_height"]), np.asarray(z["weight_coef_tapes"]),
                             float(z["weight_sd_from_girths"]))
        card = json.loads(str(z["card"]))
    except (KeyError, ValueError, RuntimeError, TypeError) as exc:
        raise TryonError(f"{path} is not a body-from-photos model ({exc})") from exc
    net.eval()
    return PhotoModel(net, baseline, weight, card)
