"""`tryon bench ablations`: ablations of the draping network (the dissertation's tables 6.2-6.3 in spirit): the
same data, split, seed and epochs, one loss term or one decoder feature taken away at a
time, each variant judged on the test split like `tryon bench learned` judges the model.

`tryon bench ablations --data DIR --json OUT` trains every variant into a folder next to
OUT (each resumes from its own checkpoint, so a stopped run continues)."""

from __future__ import annotations

import copy
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from tryon.bench.records import progress_line
from tryon.errors import TryonError
from tryon.io.atomic import atomic_write
from tryon.io.json_safe import dumps_json
from tryon.learn.train import TrainConfig


@dataclass(frozen=True)
class Ablation:
    name: str
    what: str                                # what the variant lacks, for people
    change: Callable[[TrainConfig], None]    # applied to a copy of the full model's settings


def _zero(*terms: str) -> Callable[[TrainConfig], None]:
    def change(c: TrainConfig) -> None:
        for t in terms:
            setattr(c.weights, t, 0.0)
    return change


def _net(**values) -> Callable[[TrainConfig], None]:
    def change(c: TrainConfig) -> None:
        for k, v in values.items():
            setattr(c.net, k, v)
    return change


def _both(*changes: Callable[[TrainConfig], None]) -> Callable[[TrainConfig], None]:
    def change(c: TrainConfig) -> None:
        for f in changes:
            f(c)
    return change


ABLATIONS: tuple[Ablation, ...] = (
    Ablation("full", "nothing: every loss term and decoder feature", lambda c: None),
    Ablation("no-direction", "the direction loss (c outside the body, d along the truth)", _zero("direction")),
    Ablation("no-penetration", "the penetration term", _zero("penetration")),
    Ablation("no-edge", "the relative edge-length loss", _zero("edge")),
    Ablation("no-deformation", "the deformation-gradient loss", _zero("deformation")),
    Ablation("no-laplacian", "the per-level Laplacian loss", _zero("laplacian")),
    Ablation("v2v-only", "every term but V2V on the finest level", _zero("direction", "penetration", "edge", "deformation",
                                                                             "laplacian", "spectral", "levels")),
    Ablation("no-spectral-branch", "the spectral branch (and its loss)", _both(_net(spectral=False), _zero("spectral"))),
    Ablation("fixed-aggregation", "learned aggregation weights (theta fixed to 1 / degree)", _net(learned_aggregation=False)),
    Ablation("one-level", "the hierarchy: the decoder on the finest mesh only", _both(_net(levels=1), _zero("levels"))),
)
BY_NAME = {a.name: a for a in ABLATIONS}


def ablation_config(name: str, base: TrainConfig) -> TrainConfig:
    if name not in BY_NAME:
        raise TryonError(f"unknown ablation {name!r}; known: {', '.join(BY_NAME)}")
    config = copy.deepcopy(base)
    BY_NAME[name].change(config)
    return config


def run_ablations(json_path: str | Path, data_dir: str | Path, names: list[str] | None = None, epochs: int = 40,
                  progress: bool = True, split: str = "test") -> dict:
    """Train and judge every named variant (default: all) on `split`; records in the order named."""
    from tryon.dataset.loading import load_drape_dataset
    from tryon.learn.data import training_set
    from tryon.learn.evaluate import Judge
    from tryon.learn.train import predict_set, train_drape

    names = names or [a.name for a in ABLATIONS]
    for n in names:
        ablation_config(n, TrainConfig())  # unknown names fail before any training
    json_path = Path(json_path)
    folder = json_path.with_name(json_path.stem + "-models")
    folder.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    data = load_drape_dataset(data_dir)
    records = []
    for n in names:
        config = ablation_config(n, TrainConfig(epochs=epochs))
        if progress:
            progress_line("ablations", f"training {n!r} ({len(records) + 1} of {len(names)}), {epochs} epochs", t0)
        t = time.perf_counter()
        model = train_drape(data_dir, folder / n, config, progress=progress)
        ts = training_set(data, model.priors, model.region, progress=False)
        test = ts.subset(ts.split == split)
        if len(test.rows) == 0:
            raise TryonError(f"{data_dir} has no {split} bodies to judge the ablations on")
        rec = Judge(data, test, model).record(n, split, predict_set(model, test), float("nan"))
        rec.pop("inference_ms"), rec.pop("refine_s"), rec.pop("simulation_s")
        rec.update({"ablation": n, "lacks": BY_NAME[n].what, "epochs": epochs, "best_epoch": model.card.get("best_epoch"),
                    "train_s": time.perf_counter() - t})
        records.append(rec)
        _write(json_path, data_dir, records, t0)
    full = next((r for r in records if r["ablation"] == "full"), None)
    for r in records:
        r["error_vs_full"] = r["mean_error_cm"] / full["mean_error_cm"] if full else None
    return _write(json_path, data_dir, records, t0)


def _write(json_path: Path, data_dir, records: list[dict], t0: float) -> dict:
    out = {"bench": "ablations", "data": str(data_dir), "threads": torch.get_num_threads(), "records": records,
           "wall_s": time.perf_counter() - t0}
    with atomic_write(json_path) as fh:
        fh.write(dumps_json(out, indent=1))
    return out


def ablation_table(records: list[dict]) -> str:
    """A markdown table of the records (docs/LEARNED.md)."""
    rows = ["| variant | lacks | mean cm | p95 cm | inside % | edge error % | vs full |", "|---|---|---:|---:|---:|---:|---:|"]
    for r in records:
        ratio = r.get("error_vs_full")
        rows.append(f"| {r['ablation']} | {r['lacks']} | {r['mean_error_cm']:.2f} | {r['p95_error_cm']:.2f} | "
                    f"{r['interpenetration_pct']:.2f} | {r['edge_error_pct']:.2f} | "
                    f"{'' if ratio is None or not np.isfinite(ratio) else f'{ratio:.2f}'} |")
    return "\n".join(rows)
