"""The fabric class from a clip (fabric from video, docs/FABRIC_FROM_VIDEO.md), after the
temporal classifier of chapter 4: per frame an image feature (the person finder's mask and
keypoints, as the body from photos reads them) and a garment feature (the garment's code,
`garment_codes`), an LSTM over the frames, and the 54 fabric classes out.

`METHODS` are the chapter's ablations: what the network sees (`image+garment`, `image-only`,
`garment-only`) and how frames are joined (`-temporal`: the LSTM; `-frame`: each frame
classified alone, the frames' class scores averaged).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from torch import nn

from tryon.errors import TryonError

METHODS = tuple(f"{inputs}-{join}" for inputs in ("image+garment", "image-only", "garment-only")
                for join in ("temporal", "frame"))
MASK = 64  # px: the person's and the garment's masks in the crop, as the classifier reads them
KEYPOINTS = 33


def method_parts(method: str) -> tuple[bool, bool, bool]:
    """(sees the image, sees the garment, temporal) of a method name."""
    if method not in METHODS:
        raise TryonError(f"unknown method {method!r}; use one of {', '.join(METHODS)}")
    inputs, join = method.rsplit("-", 1)
    return inputs != "garment-only", inputs != "image-only", join == "temporal"


@dataclass
class ClipTensors:
    """Clips as the classifier reads them (numpy, row = clip)."""

    masks: np.ndarray      # [N,T,2,MASK,MASK] uint8 (0/1): per frame the person's mask and the garment's found in it
    keypoints: np.ndarray  # [N,T,KEYPOINTS*3] float32: x, y in the crop (0-1) and visibility
    codes: np.ndarray      # [N,T,CODE] float32: the garment's code per frame
    label: np.ndarray      # [N] fabric class
    split: np.ndarray      # [N] train / val / test
    garment: np.ndarray    # [N] garment name

    def rows(self, split: str) -> np.ndarray:
        return np.nonzero(self.split == split)[0]


def frame_masks(person_bits: np.ndarray, garment_bits: np.ndarray) -> np.ndarray:
    """[T,2,MASK,MASK] uint8 from a clip's packed masks: the person's (128 px in the crop,
    halved by 2 x 2 maxima) and the garment's found in the picture (64 px)."""
    t = len(person_bits)
    person = np.unpackbits(person_bits, axis=-1).reshape(t, 2 * MASK, 2 * MASK)
    person = person.reshape(t, MASK, 2, MASK, 2).max(axis=(2, 4))
    garment = np.unpackbits(garment_bits, axis=-1).reshape(t, MASK, MASK)
    return np.stack([person, garment], axis=1).astype(np.uint8)


def frame_inputs(mask_bits: np.ndarray, garment_bits: np.ndarray, keypoints: np.ndarray,
                 visibility: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A clip's frames as the classifier reads them, from what `frame_features` stores per
    frame (stacked over T frames): masks [T,2,MASK,MASK] uint8 and keypoints [T,99] float32."""
    kp = np.concatenate([keypoints.astype(np.float32), visibility.astype(np.float32)[..., None]], -1)
    return frame_masks(mask_bits, garment_bits), kp.reshape(len(kp), -1)


def clip_tensors(folders: list[str | Path], codes_model, seed: int = 0) -> ClipTensors:
    """The ok clips of clip datasets (`tryon dataset clips`) with every frame's garment
    coded by `codes_model` (a `GarmentCodes`; each frame's cloud drawn from the seed)."""
    from tryon.dataset.clips import KIND
    from tryon.dataset.loading import reference_garments
    from tryon.dataset.store import DatasetError, Manifest, ShardStore, sample_rows
    from tryon.learn.garment_codes import centred_cloud

    rng = np.random.default_rng(seed)
    parts: dict[str, list] = {k: [] for k in ("masks", "keypoints", "codes", "label", "split", "garment")}
    for folder in folders:
        folder = Path(folder)
        manifest = Manifest.read(folder)
        if manifest.kind != KIND:
            raise DatasetError(f"{folder} holds a {manifest.kind!r} dataset, not clips")
        arrays = ShardStore(folder, manifest).load()
        missing = sorted({"frame_mask_bits", "frame_found_garment_bits", "frame_keypoints", "frame_visibility",
                          "fabric_class", "x"} - set(arrays))
        if missing:
            raise DatasetError(f"{folder}: its clips lack {', '.join(missing)} (made by an older generator); make "
                               "the dataset again")
        faces = next(iter(reference_garments(folder).values())).faces
        for r in sample_rows(arrays):
            t = arrays["x"][r].shape[0]
            masks, kp = frame_inputs(*(arrays[f"frame_{k}"][r] for k in ("mask_bits", "found_garment_bits",
                                                                          "keypoints", "visibility")))
            parts["masks"].append(masks)
            parts["keypoints"].append(kp)
            clouds = np.stack([centred_cloud(arrays["x"][r][k].astype(np.float64), faces, rng, codes_model.config.cloud)
                               for k in range(t)])
            with torch.no_grad():
                parts["codes"].append(codes_model.encode(torch.from_numpy(clouds)).numpy())
            parts["label"].append(int(arrays["fabric_class"][r]))
            split = str(arrays["split"][r])
            parts["split"].append("test" if split == "extrapolation" else split)
            parts["garment"].append(manifest.spec["garment"])
    if not parts["label"]:
        raise TryonError(f"no finished clips in {', '.join(map(str, folders))}")
    return ClipTensors(np.stack(parts["masks"]).astype(np.uint8), np.stack(parts["keypoints"]),
                       np.stack(parts["codes"]).astype(np.float32), np.asarray(parts["label"]),
                       np.asarray(parts["split"]), np.asarray(parts["garment"]))


class FabricFromClip(nn.Module):
    """Per-frame features (image: mask CNN + keypoint MLP; garment: code MLP), joined over
    the frames by an LSTM (temporal) or by averaging each frame's class scores."""

    def __init__(self, method: str = "image+garment-temporal", classes: int = 54, code: int = 128, hidden: int = 64):
        super().__init__()
        self.method, self.classes = method, classes
        self.image, self.garment, self.temporal = method_parts(method)
        width = 0
        if self.image:
            self.mask_cnn = nn.Sequential(
                nn.Conv2d(2, 8, 5, stride=2, padding=2), nn.ReLU(), nn.Conv2d(8, 16, 3, stride=2, padding=1), nn.ReLU(),
                nn.Conv2d(16, 32, 3, stride=2, padding=1), nn.ReLU(),
                nn.AdaptiveAvgPool2d(8), nn.Flatten(), nn.Linear(2048, hidden), nn.ReLU())
            self.keypoint_mlp = nn.Sequential(nn.Linear(3 * KEYPOINTS, hidden), nn.ReLU())
            width += 2 * hidden
        if self.garment:
            self.code_mlp = nn.Sequential(nn.Linear(code, hidden), nn.ReLU())
            width += hidden
        if self.temporal:
            self.lstm = nn.LSTM(width, hidden, batch_first=True)
            self.head = nn.Linear(hidden, classes)
        else:
            self.head = nn.Sequential(nn.Linear(width, hidden), nn.ReLU(), nn.Linear(hidden, classes))

    def features(self, masks: torch.Tensor, keypoints: torch.Tensor, codes: torch.Tensor) -> torch.Tensor:
        """[B,T,width] per-frame features."""
        b, t = codes.shape[:2]
        parts = []
        if self.image:
            m = masks.reshape(b * t, *masks.shape[2:]).float()
            parts += [self.mask_cnn(m).view(b, t, -1), self.keypoint_mlp(keypoints)]
        if self.garment:
            parts.append(self.code_mlp(codes))
        return torch.cat(parts, -1)

    def forward(self, masks: torch.Tensor, keypoints: torch.Tensor, codes: torch.Tensor) -> torch.Tensor:
        """Class scores [B,classes] (logits)."""
        f = self.features(masks, keypoints, codes)
        if self.temporal:
            out, _ = self.lstm(f)
            return self.head(out[:, -1])
        return self.head(f).mean(1)


def batch(clips: ClipTensors, rows: np.ndarray) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    return (torch.from_numpy(clips.masks[rows]), torch.from_numpy(clips.keypoints[rows]),
            torch.from_numpy(clips.codes[rows]), torch.from_numpy(clips.label[rows]))


def accuracy(model: FabricFromClip, clips: ClipTensors, rows: np.ndarray, bin_distance=None) -> dict:
    """top1 / top3 (fractions) and, given `bin_distance(a, b)`, the share within one bin."""
    if not len(rows):
        return {"count": 0}
    with torch.no_grad():
        scores = torch.cat([model(*batch(clips, rows[i:i + 64])[:3]) for i in range(0, len(rows), 64)])
    truth = torch.from_numpy(clips.label[rows])
    top3 = scores.topk(min(3, scores.shape[1]), dim=1).indices
    out = {"count": int(len(rows)), "top1": float((top3[:, 0] == truth).float().mean()),
           "top3": float((top3 == truth[:, None]).any(1).float().mean())}
    if bin_distance is not None:
        near = [bin_distance(int(p), int(t)) <= 1 for p, t in zip(top3[:, 0], truth)]
        out["within_one_bin"] = float(np.mean(near))
    return out
