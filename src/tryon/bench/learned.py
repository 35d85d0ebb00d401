"""`tryon bench learned`: the draping network against its baselines on a dataset's
held-out splits (test and extrapolation), one record per method and split.

Methods: `learned` (the model), `learned+refine` (relaxed by the simulator,
tryon.learn.refine), `skinning` (its prior: the reference drape carried by
skinning), `nearest` (nearest training body of the same gender and size) and
`tailornet-pca` (MLP to PCA coefficients, L2), the last two fitted on the dataset's
training split here (left out on data without one, such as the held-out drapes that ship
with the model). Keys per record: method, split, garment, fabric (`all`, or on data whose
fabric is drawn per drape also one record per fabric for the learned methods, without
error_vs_skinning), samples, mean_error_cm,
p95_error_cm, interpenetration_pct, edge_error_pct, potential_ratio, inference_ms,
refine_s, simulation_s, and error_vs_skinning (mean error over the skinning baseline's).
`outside_dataset` holds `tryon drape --method learned --refine` against `tryon drape` on
people outside the dataset (tryon.bench.learned_vs_drape; not with `quick`).
`<json>-comparison.png` shows the test drape of median error: learned, refined, simulated."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import torch

from tryon.bench.records import progress_line
from tryon.io.atomic import atomic_write
from tryon.io.json_safe import dumps_json

SPLITS = ("test", "extrapolation")


def _refined(model, data, judge, learned, started: float) -> tuple[np.ndarray, float, np.ndarray]:
    """The learned predictions relaxed by the simulator in each drape's fabric: (positions,
    inference ms, refine s per drape)."""
    from tryon.learn.data import GENDERS
    from tryon.learn.refine import refine_drape

    pred, ms = learned
    sizes = data.manifest.spec["sizes"]
    out, secs = np.zeros_like(pred), []
    for i, body in enumerate(judge.bodies):
        garment = model.reference_garment(GENDERS[int(judge.ts.gender[i])], sizes[int(judge.ts.size[i])])
        x, stats = refine_drape(pred[i].astype(float), garment, body, judge.fabrics[i])
        out[i], _ = x, secs.append(stats["refine_s"])
        progress_line("learned", f"refined {i + 1} of {len(judge.bodies)} in {stats['refine_s']:.1f} s", started)
    return out, ms, np.asarray(secs)


def run_learned_bench(json_path: str | Path, data_dir: str | Path, model_path: str | Path | None = None,
                      quick: bool = False, per_split: int | None = None) -> dict:
    """Judge every method on the held-out splits (at most `per_split` drapes of each, evenly
    spread; `quick` without `per_split`: 6) and write the records to `json_path`."""
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
    baselines = {}
    if len(train.rows):  # the shipped held-out drapes have no training split to fit them on
        baselines = {"nearest": NearestNeighbour(train),
                     "tailornet-pca": TailorNetPCA(train, len(model.sizes), iterations=300 if quick else 3000)}
    net = model.build_net().eval()

    def one_learned(sub):
        def run(i: int):
            b = batch_tensors(sub, np.array([i]), model)
            with torch.no_grad():
                net(b["body_in"], b["gender"], b["size"], b["prior"], b["fabric"])
        return run

    records = []
    picture = None
    for split in SPLITS:
        sub = ts.subset(ts.split == split)
        limit = per_split if per_split is not None else (6 if quick else None)
        if limit is not None and len(sub.rows) > limit:  # evenly spread over the split's bodies and sizes
            sub = sub.subset(np.unique(np.linspace(0, len(sub.rows) - 1, limit).round().astype(int)))
        if len(sub.rows) == 0:
            continue
        progress_line("learned", f"{split} split: {len(sub.rows)} drapes, every method", t0)
        judge = Judge(data, sub, model)
        methods = {"learned": timed(lambda s: predict_set(model, s), sub, one_learned(sub)),
                   "skinning": timed(lambda s: s.prior, sub)}
        methods.update({name: timed(b.predict, sub) for name, b in baselines.items()})
        refined = _refined(model, data, judge, methods["learned"], t0)
        measured = {name: judge.measures(pred) for name, (pred, _) in methods.items()}
        measured["learned+refine"] = judge.measures(refined[0])
        rows = {name: judge.record(name, split, pred, ms, measures=measured[name]) for name, (pred, ms) in methods.items()}
        rows["learned+refine"] = judge.record("learned+refine", split, refined[0], refined[1], float(refined[2].mean()),
                                              measures=measured["learned+refine"])
        if split == "test":
            picture = comparison_picture(model, judge, methods["learned"][0], refined[0])
        for r in rows.values():
            r["error_vs_skinning"] = r["mean_error_cm"] / rows["skinning"]["mean_error_cm"]
        records.extend(rows.values())
        if len(set(judge.fabric_labels)) > 1:  # drawn fabrics: the model's error in each
            records.extend(judge.records_by_fabric("learned", split, *methods["learned"], measures=measured["learned"]))
            records.extend(judge.records_by_fabric("learned+refine", split, *refined, measures=measured["learned+refine"]))
    from tryon.bench.learned_vs_drape import outside_dataset_records

    if not quick:
        progress_line("learned", "people outside the dataset: learned and refined against tryon drape", t0)
    outside = "left out of --quick" if quick else outside_dataset_records(model, data.manifest.spec["fabric"])
    out = {"bench": "learned", "data": str(data_dir), "model": str(model_path or "shipped"), "per_split": per_split,
           "baselines": sorted(baselines) if baselines else "nearest and tailornet-pca need the dataset's training "
                                                           "split: give --data DATASET",
           "model_card": {k: model.card.get(k) for k in ("trained", "samples", "best_epoch", "metrics")},
           "threads": torch.get_num_threads(), "records": records, "outside_dataset": outside,
           "wall_s": time.perf_counter() - t0}
    with atomic_write(json_path) as fh:
        fh.write(dumps_json(out, indent=1))
    if picture is not None:
        from tryon.render.offscreen import save_png

        save_png(Path(json_path).with_name(Path(json_path).stem + "-comparison.png"), picture)
    return out


ERROR_SCALE_CM = 2.0  # top of the comparison picture's error colours


def comparison_picture(model, judge, learned: np.ndarray, refined: np.ndarray) -> np.ndarray:
    """The test drape of median learned error, front view: the prediction and the refined
    prediction coloured by each vertex's distance to the simulated drape, and the
    simulated drape itself in its fabric's colour, labelled with their mean errors."""
    from PIL import Image, ImageDraw

    from tryon.drape.outputs import render_views
    from tryon.render.appearance import appearance
    from tryon.render.colormap import add_colorbar, label_font, scalar_to_rgb

    ts = judge.ts
    err = {name: 100.0 * np.linalg.norm(x - ts.truth, axis=-1) for name, x in (("learned", learned), ("refined", refined))}
    i = int(np.argsort(err["learned"].mean(1))[len(ts.rows) // 2])
    body = judge.bodies[i]
    faces = model.faces
    panels = []
    for title, x, e in (("learned", learned[i], err["learned"][i]), ("learned + refine", refined[i], err["refined"][i]),
                        ("simulated", ts.truth[i], None)):
        if e is None:
            colors = np.tile(np.asarray(appearance(judge.fabric_labels[i]).color), (len(x), 1))
        else:
            colors = scalar_to_rgb(e, 0.0, ERROR_SCALE_CM, cmap="turbo")
        img = render_views(body.vertices, body.faces, x.astype(float), faces, colors, size=(420, 620), views=("front",))[0]
        pil = Image.fromarray(img[..., :3])
        text = title if e is None else f"{title}: mean {e.mean():.2f} cm"
        ImageDraw.Draw(pil).text((10, 10), text, fill=(0, 0, 0), font=label_font(22))
        panels.append(np.asarray(pil))
    return add_colorbar(np.concatenate(panels, axis=1), 0.0, ERROR_SCALE_CM, cmap="turbo",
                        label="distance to the simulated drape (cm)", fmt="{:.1f}")
