"""The body from photos: a multi-view, multi-stage recurrent regression (Liang's
dissertation, ch.2) over what the person finder sees in each view.

Each view is encoded from its mask crop (a small CNN) and its 33 keypoints (an MLP) into
one feature. One shared body state (every tape measurement, as a residual from what
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
CAMERA = 5  # cos yaw, sin yaw, scale, x offset, y offset (weak perspective on the crop)


@dataclass
class RegressorConfig:
    crop: int = 128
    feature: int = 256
    hidden: int = 512
    stages: int = 3
    measurements: int = 16
    shape: int = 32
    joints: int = 15

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


def condition(height_cm, weight_kg, gender) -> np.ndarray:
    """The network's person inputs [N,3]: stature, weight (normalised) and gender."""
    return np.stack([(np.asarray(height_cm) - 170.0) / 10.0, (np.asarray(weight_kg) - 75.0) / 15.0,
                     np.asarray(gender, np.float64)], -1).astype(np.float32)


class ViewEncoder(nn.Module):
    """A view's mask crop [B,1,C,C] and keypoints [B,33,3] (x, y in the crop, visibility)
    to one feature [B,F]."""

    def __init__(self, cfg: RegressorConfig):
        super().__init__()
        chans = (1, 16, 32, 64, 96)
        layers: list[nn.Module] = []
        for a, b in zip(chans[:-1], chans[1:]):
            layers += [nn.Conv2d(a, b, 3, stride=2, padding=1), nn.GroupNorm(4, b), nn.ReLU()]
        self.cnn = nn.Sequential(*layers)
        side = cfg.crop // 16
        self.mask_fc = nn.Linear(chans[-1] * side * side, cfg.feature)
        self.kp = nn.Sequential(nn.Linear(KEYPOINTS * 3, 256), nn.ReLU(), nn.Linear(256, cfg.feature))
        self.mix = nn.Sequential(nn.ReLU(), nn.Linear(2 * cfg.feature, cfg.feature), nn.ReLU())

    def forward(self, mask: torch.Tensor, keypoints: torch.Tensor) -> torch.Tensor:
        m = self.mask_fc(self.cnn(mask).flatten(1))
        k = self.kp(keypoints.flatten(1))
        return self.mix(torch.cat([m, k], 1))


class BodyFromViews(nn.Module):
    """The multi-view, multi-stage recurrent regression; see the module docstring."""

    def __init__(self, cfg: RegressorConfig):
        super().__init__()
        self.cfg = cfg
        self.encoder = ViewEncoder(cfg)
        state = cfg.measurements + CAMERA + 3
        self.blocks = nn.ModuleList([
            nn.Sequential(nn.Linear(cfg.feature + state, cfg.hidden), nn.ReLU(), nn.Linear(cfg.hidden, cfg.hidden),
                          nn.ReLU(), nn.Linear(cfg.hidden, cfg.measurements + CAMERA))
            for _ in range(cfg.stages)])
        head_in = cfg.measurements + 3
        self.log_sd = nn.Sequential(nn.Linear(head_in + cfg.feature, 128), nn.ReLU(), nn.Linear(128, cfg.measurements))
        self.shape = nn.Sequential(nn.Linear(head_in, 128), nn.ReLU(), nn.Linear(128, cfg.shape))
        self.joints = nn.Sequential(nn.Linear(head_in, 128), nn.ReLU(), nn.Linear(128, cfg.joints * 3))

    def forward(self, mask: torch.Tensor, keypoints: torch.Tensor, present: torch.Tensor,
                cond: torch.Tensor) -> dict[str, torch.Tensor]:
        """mask [B,V,1,C,C], keypoints [B,V,33,3], present [B,V] (0/1), cond [B,3]."""
        B, V = present.shape
        feats = self.encoder(mask.flatten(0, 1), keypoints.flatten(0, 1)).view(B, V, -1)
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


def save_model(path: str | Path, net: BodyFromViews, baseline: HeightWeightBaseline, card: dict) -> Path:
    """The model as one .npz (weights, baseline, config and card as JSON; no pickle)."""
    from tryon.io.atomic import atomic_write

    arrays = {f"w/{k}": v.detach().numpy() for k, v in net.state_dict().items()}
    arrays.update({"baseline_coef": baseline.coef, "baseline_sd": baseline.sd,
                   "config": np.asarray(json.dumps(net.cfg.to_dict())), "card": np.asarray(json.dumps(card))})
    with atomic_write(path, "wb") as fh:
        np.savez_compressed(fh, **arrays)
    return Path(path)


def load_model(path: str | Path) -> tuple[BodyFromViews, HeightWeightBaseline, dict]:
    from tryon.io.npz import read_npz

    z = read_npz(Path(path), "body-from-photos model")
    try:
        cfg = RegressorConfig(**json.loads(str(z["config"])))
        net = BodyFromViews(cfg)
        net.load_state_dict({k[2:]: torch.from_numpy(np.asarray(v)) for k, v in z.items() if k.startswith("w/")})
        baseline = HeightWeightBaseline(np.asarray(z["baseline_coef"]), np.asarray(z["baseline_sd"]))
        card = json.loads(str(z["card"]))
    except (KeyError, ValueError, RuntimeError, TypeError) as exc:
        raise TryonError(f"{path} is not a body-from-photos model ({exc})") from exc
    net.eval()
    return net, baseline, card
