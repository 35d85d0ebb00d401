"""`tryon train fabric-video`: the fabric class from clips (`fabric_video`) on clip datasets
(`tryon dataset clips`), one method or every ablation.

Fixed seed, a checkpoint every epoch (the same command resumes), the model with the best
validation top-1 kept, and a model card with the data and the held-out top-1, top-3 and
within-one-bin accuracy.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch

from tryon.errors import TryonError
from tryon.io.atomic import atomic_write
from tryon.learn.checkpoints import CHECKPOINT, EpochLoop, load_weights, save_weights
from tryon.learn.fabric_video import ClipTensors, FabricFromClip, accuracy, batch

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
    meta = {"method": model.method, "classes": model.classes, "code": _code_width(model)}
    return save_weights(path, model, meta=meta, card=card)


def _code_width(model: FabricFromClip) -> int:
    return int(model.code_mlp[0].in_features) if model.garment else 128


def load_classifier(path: str | Path) -> tuple[FabricFromClip, dict]:
    state, fields = load_weights(path)
    meta = fields["meta"]
    model = FabricFromClip(meta["method"], meta["classes"], meta["code"])
    try:
        model.load_state_dict(state)
    except RuntimeError as exc:
        raise TryonError(f"{path} was made by another version of the fabric classifier's network; train it again "
                         f"({str(exc).splitlines()[0]})") from exc
    model.eval()
    return model, fields["card"]


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
    val_rows = clips.rows("val") if len(clips.rows("val")) else train

    def step(rows: np.ndarray) -> torch.Tensor:
        masks, keypoints, codes, label = batch(clips, rows)
        return torch.nn.functional.cross_entropy(model(masks, keypoints, codes), label)

    loop = EpochLoop(config.epochs, config.batch, config.seed, higher_is_better=True,
                     desc=f"fabric from video ({method})", score_name="val_top1")
    loop.run(out, model, torch.optim.Adam(model.parameters(), lr=config.lr), train, step,
             validate=lambda: accuracy(model, clips, val_rows)["top1"],
             keep_best=lambda: save_classifier(model, out / MODEL, {}), progress=progress)
    kept, _ = load_classifier(out / MODEL)
    card = {"model": f"fabric class from a clip: {method} (tryon.learn.fabric_video)", "method": method,
            "classes": classes, "training": config.to_dict(), "data": data or [],
            "clips": {s: int(len(clips.rows(s))) for s in ("train", "val", "test")},
            "chance_top1": 1.0 / classes, "best_val_top1": loop.best,
            "test": accuracy(kept, clips, clips.rows("test"), bin_distance), "history": loop.history,
            "seconds_this_run": loop.seconds}
    save_classifier(kept, out / MODEL, card)
    with atomic_write(out / "model_card.json", "w") as fh:
        fh.write(json.dumps(card, indent=1))
    return card

