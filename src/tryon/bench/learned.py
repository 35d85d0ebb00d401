"""`tryon bench learned`: the draping network against its baselines on a dataset's
held-out splits (test and extrapolation), one record per method and split.

Methods: `learned` (the model), `learned+refine` (relaxed by the simulator,
tryon.learn.refine), `skinning` (its prior: the reference drape carried by
skinning), `nearest` (nearest training body of the same gender and size) and
`tailornet-pca` (MLP to PCA coefficients, L2), the last two fitted on the dataset's
training split here. Keys per record: method, split, samples, mean_error_cm,
p95_error_cm, interpenetration_pct, edge_error_pct, potential_ratio, inference_ms,
refine_s, simulation_s, and error_vs_skinning (mean error over the skinning baseline's)."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import torch

from tryon.io.atomic import atomic_write
from tryon.io.json_safe import dumps_json

SPLITS = ("test", "extrapolation")


def _refined(model, data, judge, learned) -> tuple[np.ndarray, float, float]:
    """The learned predictions relaxed by the simulator: (positions, inference ms, mean refine s)."""
    from tryon.fabric import load_fabric
    from tryon.learn.data import GENDERS
    from tryon.learn.refine import refine_drape

    pred, ms = learned
    fabric = load_fabric(data.manifest.spec["fabric"])
    sizes = data.manifest.spec["sizes"]
    out, secs = np.zeros_like(pred), []
    for i, body in enumerate(judge.bodies):
        garment = model.reference_garment(GENDERS[int(judge.ts.gender[i])], sizes[int(judge.ts.size[i])])
        x, stats = refine_drape(pred[i].astype(float), garment, body, fabric)
        out[i], _ = x, secs.append(stats["refine_s"])
    return out, ms, float(np.mean(secs))


def run_learned_bench(json_path: str | Path, data_dir: str | Path, model_path: str | Path | None = None,
                      quick: bool = False) -> dict:
    from tryon.dataset.loading import load_drape_dataset
    from tryon.learn.baselines import NearestNeighbour, TailorNetPCA
    from tryon.learn.data import training_set
    from tryon.learn.evaluate import Judge, timed
    from tryon.learn.model import DrapeModel, load_shipped
    from tryon.learn.train import batch_tensors, predict_set

    t0 = time.perf_counter()
    data = load_drape_dataset(data_dir)
    model = DrapeModel.load(model_path) if model_path else load_shipped(data.manifest.spec["garment"])
    model.check_dataset(data.manifest.spec)
    ts = training_set(data, model.priors, model.region, progress=False)
    train = ts.subset(ts.split == "train")
    baselines = {"nearest": NearestNeighbour(train),
                 "tailornet-pca": TailorNetPCA(train, len(model.sizes), iterations=300 if quick else 3000)}
    net = model.build_net().eval()

    def one_learned(sub):
        def run(i: int):
            b = batch_tensors(sub, np.array([i]), model)
            with torch.no_grad():
                net(b["body_in"], b["gender"], b["size"], b["prior"])
        return run

    records = []
    for split in SPLITS:
        sub = ts.subset(ts.split == split)
        if quick:
            sub = sub.subset(np.arange(min(6, len(sub.rows))))
        if len(sub.rows) == 0:
            continue
        judge = Judge(data, sub, model)
        methods = {"learned": timed(lambda s: predict_set(model, s), sub, one_learned(sub)),
                   "skinning": timed(lambda s: s.prior, sub)}
        methods.update({name: timed(b.predict, sub) for name, b in baselines.items()})
        rows = {name: judge.record(name, split, pred, ms) for name, (pred, ms) in methods.items()}
        rows["learned+refine"] = judge.record("learned+refine", split, *_refined(model, data, judge, methods["learned"]))
        for r in rows.values():
            r["error_vs_skinning"] = r["mean_error_cm"] / rows["skinning"]["mean_error_cm"]
        records.extend(rows.values())
    out = {"bench": "learned", "data": str(data_dir), "model": str(model_path or "shipped"),
           "model_card": {k: model.card.get(k) for k in ("trained", "samples", "best_epoch", "metrics")},
           "threads": torch.get_num_threads(), "records": records, "wall_s": time.perf_counter() - t0}
    with atomic_write(json_path) as fh:
        fh.write(dumps_json(out, indent=1))
    return out
