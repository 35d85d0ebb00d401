"""`tryon train fabric-video`: the fabric class from clips (`fabric_video`) on clip datasets
(`tryon dataset clips`), one method or every ablation.

Fixed seed, a checkpoint every epoch (the same command resumes), the model with the best
validation top-1 kept, and a model card with the data and the held-out top-1, top-3 and
within-one-bin accuracy.
"""

from __future__ import annotations

import json
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from tryon.errors import TryonError
from tryon.io.atomic import atomic_write
from tryon.learn.fabric_video import ClipTensors, FabricFromClip, accuracy, batch

CHECKPOINT = "checkpoint.pt"
MODEL = "fabric-video.npz"


@dataclass
class ClassifierTrainConfig:
    epochs: int = 60
    batch: int = 16
    lr: float = 1e-3
    seed: int = 0

    def to_dict(self) -> dict:
        return asdict(self)


def save_classifier(model: FabricFromClip, path: Path, card: dict) -> Path:
    arrays = {f"param/{k}": v.detach().numpy() for k, v in model.state_dict().items()}
    meta = {"method": model.method, "classes": model.classes, "code": _code_width(model)}
    with atomic_write(path, "wb") as fh:
        np.savez(fh, meta=np.asarray(json.dumps(meta)), card=np.asarray(json.dumps(card)), **arrays)
    return path


def _code_width(model: FabricFromClip) -> int:
    return int(model.code_mlp[0].in_features) if model.garment else 128


def load_classifier(path: str | Path) -> tuple[FabricFromClip, dict]:
    with np.load(path, allow_pickle=False) as z:
        meta = json.loads(str(z["meta"]))
        model = FabricFromClip(meta["method"], meta["classes"], meta["code"])
        model.load_state_dict({k[len("param/"):]: torch.from_numpy(z[k]) for k in z.files if k.startswith("param/")})
        card = json.loads(str(z["card"]))
    model.eval()
    return model, card


def train_classifier(clips: ClipTensors, out: str | Path, method: str, config: ClassifierTrainConfig | None = None,
                     classes: int = 54, bin_distance=None, data: list[str] | None = None, progress: bool = True,
                     force: bool = False) -> dict:
    """Train (or resume) one method into `out`; returns the model card."""
    from tryon.io.atomic import claim_work_dir, is_owned

    config = config or ClassifierTrainConfig()
    out = Path(out)
    train = clips.rows("train")
    if len(train) < 2:
        raise TryonError(f"only {len(train)} training clips: make more first")
    claim_work_dir(out, resume=(out / CHECKPOINT).exists() and is_owned(out), force=force)
    torch.manual_seed(config.seed)
    model = FabricFromClip(method, classes, clips.codes.shape[-1])
    opt = torch.optim.Adam(model.parameters(), lr=config.lr)
    start, best, history = 0, -1.0, []
    ckpt = out / CHECKPOINT
    if ckpt.exists():
        state = torch.load(ckpt, weights_only=True)
        model.load_state_dict(state["model"])
        opt.load_state_dict(state["opt"])
        start, best, history = int(state["epoch"]), float(state["best"]), json.loads(state["history"])
    val_rows = clips.rows("val") if len(clips.rows("val")) else train
    rng = np.random.default_rng([config.seed, 2])
    for _ in range(start):  # replay the shuffles of the epochs done, so a resumed run repeats them
        rng.permutation(train)
    t0 = time.perf_counter()
    for epoch in tqdm(range(start, config.epochs), desc=f"fabric from video ({method})", initial=start,
                      total=config.epochs, disable=not progress):
        model.train()
        order = rng.permutation(train)
        losses = []
        for i in range(0, len(order), config.batch):
            masks, keypoints, codes, label = batch(clips, order[i:i + config.batch])
            loss = nn_loss(model(masks, keypoints, codes), label)
            opt.zero_grad()
            loss.backward()
            opt.step()
            losses.append(loss.item())
        model.eval()
        val = accuracy(model, clips, val_rows)
        history.append({"epoch": epoch + 1, "train_loss": float(np.mean(losses)), "val_top1": val["top1"]})
        if val["top1"] > best:
            best = val["top1"]
            save_classifier(model, out / MODEL, {})
        torch.save({"model": model.state_dict(), "opt": opt.state_dict(), "epoch": epoch + 1, "best": best,
                    "history": json.dumps(history)}, ckpt)
    kept, _ = load_classifier(out / MODEL)
    card = {"model": f"fabric class from a clip: {method} (tryon.learn.fabric_video)", "method": method,
            "classes": classes, "training": config.to_dict(), "data": data or [],
            "clips": {s: int(len(clips.rows(s))) for s in ("train", "val", "test")},
            "chance_top1": 1.0 / classes, "best_val_top1": best,
            "test": accuracy(kept, clips, clips.rows("test"), bin_distance), "history": history,
            "seconds_this_run": time.perf_counter() - t0}
    save_classifier(kept, out / MODEL, card)
    with atomic_write(out / "model_card.json", "w") as fh:
        fh.write(json.dumps(card, indent=1))
    return card


def nn_loss(scores: torch.Tensor, label: torch.Tensor) -> torch.Tensor:
    return torch.nn.functional.cross_entropy(scores, label)
