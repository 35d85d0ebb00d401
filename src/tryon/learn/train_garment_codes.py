"""`tryon train garment-codes`: the garment autoencoder (`garment_codes`) on drape datasets
of any garments together.

Every ok drape of every dataset given becomes one centred surface cloud (drawn once, from
the seed). Splits are the datasets' own (per body; extrapolation bodies are test). Fixed
seed, a checkpoint every epoch (the same command resumes), the best model on validation
kept, and a model card with the data and the held-out Chamfer distance per garment.
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
from tryon.learn.garment_codes import CodeConfig, GarmentCodes, centred_cloud

MODEL = "garment-codes.npz"


@dataclass
class CodeTrainConfig:
    epochs: int = 40
    batch: int = 32
    lr: float = 1e-3
    seed: int = 0

    def to_dict(self) -> dict:
        return asdict(self)


@dataclass
class Clouds:
    points: np.ndarray   # [N,CLOUD,3] float32, centred
    garment: np.ndarray  # [N] garment name
    split: np.ndarray    # [N] train / val / test


def garment_clouds(folders: list[str | Path], seed: int = 0, cloud: int | None = None) -> Clouds:
    """One centred surface cloud per ok drape of each drape dataset."""
    from tryon.dataset.loading import load_drape_dataset

    rng = np.random.default_rng(seed)
    points, garments, splits = [], [], []
    for folder in folders:
        data = load_drape_dataset(folder)
        name = data.manifest.spec["garment"]
        rows = data.rows()
        if not len(rows):
            raise TryonError(f"{folder}: no drapes that settled to learn from")
        for r in rows:
            points.append(centred_cloud(data.arrays["x"][r].astype(np.float64), data.faces, rng,
                                        cloud or CodeConfig().cloud))
            garments.append(name)
            split = str(data.arrays["split"][r])
            splits.append("test" if split == "extrapolation" else split)
    return Clouds(np.stack(points).astype(np.float32), np.asarray(garments), np.asarray(splits))


def save_codes_model(model: GarmentCodes, path: Path, card: dict) -> Path:
    return save_weights(path, model, config=model.config.to_dict(), card=card)


def load_codes_model(path: str | Path) -> tuple[GarmentCodes, dict]:
    state, fields = load_weights(path)
    model = GarmentCodes(CodeConfig(**fields["config"]))
    model.load_state_dict(state)
    model.eval()
    return model, fields["card"]


def evaluate(model: GarmentCodes, clouds: Clouds, split: str) -> dict:
    """Mean Chamfer distance (cm) of the split's clouds, overall and per garment."""
    rows = np.nonzero(clouds.split == split)[0]
    if not len(rows):
        return {"count": 0}
    with torch.no_grad():
        per = torch.cat([model.loss(torch.from_numpy(clouds.points[rows[i:i + 64]]))[1]
                         for i in range(0, len(rows), 64)]).numpy()
    out = {"count": int(len(rows)), "chamfer_cm": float(100 * per.mean())}
    for g in sorted(set(clouds.garment[rows])):
        out[f"chamfer_cm_{g}"] = float(100 * per[clouds.garment[rows] == g].mean())
    return out


def train_garment_codes(folders: list[str | Path], out: str | Path, config: CodeTrainConfig | None = None,
                        progress: bool = True, force: bool = False) -> dict:
    """Train (or resume) into `out` on the drape datasets in `folders`; returns the model card."""
    config = config or CodeTrainConfig()
    clouds = garment_clouds(folders, config.seed)
    return train_on_clouds(clouds, out, config, data=[str(f) for f in folders], progress=progress, force=force)


def train_on_clouds(clouds: Clouds, out: str | Path, config: CodeTrainConfig | None = None,
                    model_config: CodeConfig | None = None, data: list[str] | None = None, progress: bool = True,
                    force: bool = False) -> dict:
    """Train (or resume) the autoencoder on `clouds` into `out`; returns the model card."""
    from tryon.io.atomic import claim_work_dir, is_owned

    config = config or CodeTrainConfig()
    out = Path(out)
    train = np.nonzero(clouds.split == "train")[0]
    if len(train) < 2:
        raise TryonError(f"only {len(train)} training garments: make more drapes first")
    claim_work_dir(out, resume=(out / CHECKPOINT).exists() and is_owned(out), force=force)
    torch.manual_seed(config.seed)
    model = GarmentCodes(model_config)
    loop = EpochLoop(config.epochs, config.batch, config.seed, higher_is_better=False, desc="garment codes",
                     score_name="val_chamfer_cm")
    val_split = "val" if (clouds.split == "val").any() else "train"
    loop.run(out, model, torch.optim.Adam(model.parameters(), lr=config.lr), train,
             step=lambda rows: model.loss(torch.from_numpy(clouds.points[rows]))[0],
             validate=lambda: evaluate(model, clouds, val_split)["chamfer_cm"],
             keep_best=lambda: save_codes_model(model, out / MODEL, {}), progress=progress)
    best_model, _ = load_codes_model(out / MODEL)
    card = {"model": "garment codes: two-level point-cloud autoencoder (tryon.learn.garment_codes)",
            "config": best_model.config.to_dict(), "training": config.to_dict(),
            "data": data or [],
            "drapes": {s: int((clouds.split == s).sum()) for s in ("train", "val", "test")},
            "garments": sorted(set(clouds.garment.tolist())), "best_val_chamfer_cm": loop.best,
            "test": evaluate(best_model, clouds, "test"), "history": loop.history,
            "seconds_this_run": loop.seconds}
    save_codes_model(best_model, out / MODEL, card)
    with atomic_write(out / "model_card.json", "w") as fh:
        fh.write(json.dumps(card, indent=1))
    return card
