"""`tryon train drape`: train the draping network on a drape dataset.

Fixed seed, progress bar, a checkpoint every epoch (resumed when the same command runs
again), the best model on the validation split kept, and a model card with the data's
manifest and the metrics on every split."""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from tryon.dataset.loading import load_drape_datasets
from tryon.errors import TryonError
from tryon.io.atomic import atomic_write
from tryon.dataset.drapes import fabric_group
from tryon.learn.data import TrainingSet, dataset_key, model_parts, training_set
from tryon.learn.losses import DrapeLoss, LossWeights
from tryon.learn.model import DrapeModel, timestamp
from tryon.learn.network import NetConfig

CHECKPOINT = "checkpoint.pt"


@dataclass
class TrainConfig:
    epochs: int = 60
    batch: int = 4
    lr: float = 3e-3  # 1e-3 with batch 8 barely left the skinned prior in 60 epochs of 42 drapes
    seed: int = 0
    weights: LossWeights = field(default_factory=LossWeights)
    net: NetConfig = field(default_factory=NetConfig)

    def to_dict(self) -> dict:
        return {"epochs": self.epochs, "batch": self.batch, "lr": self.lr, "seed": self.seed,
                "weights": self.weights.to_dict(), "net": self.net.to_dict()}


def _with_defaults(saved: dict) -> dict:
    """A checkpoint's settings with the fields added since it was written at their defaults."""
    full = TrainConfig().to_dict()
    return {**full, **saved, "weights": {**full["weights"], **saved.get("weights", {})},
            "net": {**full["net"], **saved.get("net", {})}}


def batch_tensors(ts: TrainingSet, idx: np.ndarray, model: DrapeModel) -> dict[str, torch.Tensor]:
    body = ts.body[idx].astype(np.float64)
    inp = np.concatenate([body, 10.0 * (body - model.mean_region[None])], 2).astype(np.float32)
    onehot = np.eye(len(model.sizes), dtype=np.float32)[ts.size[idx]]
    fabric = torch.from_numpy(model.fabric_input(ts.fabric[idx])) if model.config.fabric else None
    return {"body_in": torch.from_numpy(inp), "gender": torch.from_numpy(ts.gender[idx]), "size": torch.from_numpy(onehot),
            "fabric": fabric,
            "prior": torch.from_numpy(ts.prior[idx]), "truth": torch.from_numpy(ts.truth[idx]),
            "body": torch.from_numpy(ts.body[idx]), "normals": torch.from_numpy(ts.normals[idx]),
            "cand": torch.from_numpy(ts.cand[idx].astype(np.int64))}


def predict_set(model: DrapeModel, ts: TrainingSet, batch: int = 16) -> np.ndarray:
    net = model.build_net().eval()
    out = []
    with torch.no_grad():
        for s in range(0, len(ts.rows), batch):
            b = batch_tensors(ts, np.arange(s, min(s + batch, len(ts.rows))), model)
            out.append(net(b["body_in"], b["gender"], b["size"], b["prior"], b["fabric"])[0].numpy())
    return np.concatenate(out) if out else np.zeros((0, model.hierarchy.n, 3), np.float32)


def train_drape(data_dir: str | Path | list, out: str | Path, config: TrainConfig | None = None, progress: bool = True,
                max_epochs_this_run: int | None = None, force: bool = False) -> DrapeModel:
    """Train (or resume training) a draping model on the dataset in `data_dir` (or on
    several of one garment topology: a list, the first one's references, see
    `load_drape_datasets`); the model file is `out/model.npz`, its card
    `out/model_card.json`. A folder with a checkpoint of the same settings and data
    resumes; any other folder tryon wrote is started over."""
    from tryon.io.atomic import claim_work_dir, is_owned

    config = config or TrainConfig()
    out = Path(out)
    claim_work_dir(out, resume=(out / CHECKPOINT).exists() and is_owned(out), force=force)
    folders = [Path(d) for d in (data_dir if isinstance(data_dir, (list, tuple)) else [data_dir])]
    data_dir = folders[0]
    data = load_drape_datasets(folders)
    if len(data.rows("train")) < 2:
        raise TryonError(f"{data_dir} has {len(data.rows('train'))} good training samples; make more with tryon dataset drape")
    hierarchy, priors, region = model_parts(data, data_dir, config.net.levels, config.net.eigen)
    ts = training_set(data, priors, region, cache=out / "cache", progress=progress)
    train, val = ts.subset(ts.split == "train"), ts.subset(ts.split == "val")
    selected_on = "val"
    if len(val.rows) == 0:  # a small dataset drew no validation body: select on the training error
        val, selected_on = train, "train"
    config.net.sizes = len(data.manifest.spec["sizes"])
    fabrics = fabric_normalisation(train.fabric, train.fabric_name.tolist(), data.manifest.spec)
    config.net.fabric = train.fabric.shape[1] if "mean" in fabrics else 0
    model = DrapeModel(data.manifest.spec["garment"], list(data.manifest.spec["sizes"]), config.net, hierarchy, priors,
                       region, train.body.astype(np.float64).mean(0), data.faces, dict(data.references), fabrics=fabrics)
    torch.manual_seed(config.seed)  # here: preparing the samples may draw from torch's generator
    net = model.build_net()
    loss_fn = DrapeLoss(hierarchy, config.weights)
    opt = torch.optim.Adam(net.parameters(), lr=config.lr)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, T_max=config.epochs, eta_min=config.lr * 0.02)
    state = {"epoch": 0, "best_val": float("inf"), "history": []}
    ckpt = out / CHECKPOINT
    if ckpt.exists():
        saved = torch.load(ckpt, weights_only=True)
        if _with_defaults(json.loads(saved["config"])) != config.to_dict() or saved["data"] != dataset_key(data):
            raise TryonError(f"{ckpt} was made with other settings or data; use another --out or remove it")
        net.load_state_dict(saved["net"])
        opt.load_state_dict(saved["opt"])
        sched.load_state_dict(saved["sched"])
        state = json.loads(saved["state"])
        torch.set_rng_state(saved["rng"])
    epochs_run = 0
    t0 = time.perf_counter()
    while state["epoch"] < config.epochs and (max_epochs_this_run is None or epochs_run < max_epochs_this_run):
        net.train()
        order = np.random.default_rng([config.seed, state["epoch"]]).permutation(len(train.rows))  # resumes exactly
        parts_sum: dict[str, float] = {}
        bar = tqdm(range(0, len(order), config.batch), desc=f"epoch {state['epoch'] + 1}/{config.epochs}",
                   disable=not progress, leave=False)
        for s in bar:
            b = batch_tensors(train, order[s:s + config.batch], model)
            preds = net(b["body_in"], b["gender"], b["size"], b["prior"], b["fabric"])
            truths = net.restrict(b["truth"])
            loss, parts = loss_fn(preds, truths, b["body"], b["normals"], b["cand"])
            opt.zero_grad()
            loss.backward()
            torch.nn.utils.clip_grad_norm_(net.parameters(), 10.0)
            opt.step()
            for k, v in parts.items():
                parts_sum[k] = parts_sum.get(k, 0.0) + v * len(b["cand"])
            bar.set_postfix(v2v=f"{parts['v2v']:.2f}")
        sched.step()
        val_err = mean_error_cm(predict_set(model, val), val.truth)
        if not np.isfinite(val_err) or not all(np.isfinite(v) for v in parts_sum.values()):
            raise TryonError(f"training diverged in epoch {state['epoch'] + 1} (a loss or the validation error is not finite); "
                             "lower --lr")
        state["epoch"] += 1
        epochs_run += 1
        state["history"].append({"epoch": state["epoch"], "val_mean_error_cm": val_err,
                                 **{k: v / len(order) for k, v in parts_sum.items()}})
        if val_err < state["best_val"]:
            state["best_val"] = val_err
            model.card = {"epoch": state["epoch"]}
            model.save(out / "best.npz")
        torch.save({"net": net.state_dict(), "opt": opt.state_dict(), "sched": sched.state_dict(), "rng": torch.get_rng_state(),
                    "state": json.dumps(state), "config": json.dumps(config.to_dict(), sort_keys=True), "data": dataset_key(data)},
                   out / (CHECKPOINT + ".tmp"))
        (out / (CHECKPOINT + ".tmp")).replace(ckpt)
        if progress:
            print(f"epoch {state['epoch']}: train v2v {parts_sum.get('v2v', 0) / len(order):.3f} cm, "
                  f"val mean error {val_err:.3f} cm", flush=True)
    best = DrapeModel.load(out / "best.npz")
    best.card = model_card(data, data_dir, best, ts, config, state, time.perf_counter() - t0)
    best.card["selected_on"] = selected_on
    best.save(out / "model.npz")
    with atomic_write(out / "model_card.json") as fh:
        json.dump(best.card, fh, indent=1)
    with atomic_write(out / "MODEL_CARD.md") as fh:
        fh.write(card_markdown(best.card))
    return best


def fabric_normalisation(features: np.ndarray, labels: list[str], spec: dict) -> dict:
    """How a model of many fabrics reads them: the training drapes' features centred and
    scaled by their spread, their range (beyond it the model extrapolates) and the measured
    fabrics drawn from. When every training drape wears one fabric, only its name (`labels`:
    each drape's fabric by name): a model of that one fabric."""
    f = features.astype(np.float64)
    spread = f.std(0) if len(f) else np.zeros(1)
    if spread.max() < 1e-6:
        return {"names": sorted(set(labels))[:1] or [spec["fabric"]]}
    return {"mean": f.mean(0), "scale": np.where(spread > 1e-6, spread, 1.0), "low": f.min(0), "high": f.max(0),
            "names": list(spec.get("fabrics") or [spec.get("fabric")])}


def mean_error_cm(pred: np.ndarray, truth: np.ndarray) -> float:
    return float(100.0 * np.linalg.norm(pred - truth, axis=-1).mean()) if len(truth) else float("nan")


def model_card(data, data_dir: Path, model: DrapeModel, ts: TrainingSet, config: TrainConfig, state: dict,
               wall_s: float) -> dict:
    pred = predict_set(model, ts)
    labels = np.asarray([fabric_group(n) for n in ts.fabric_name])
    metrics = {}
    for split in sorted(set(ts.split.tolist())):
        k = ts.split == split
        err = 100.0 * np.linalg.norm(pred[k] - ts.truth[k], axis=-1)
        prior = 100.0 * np.linalg.norm(ts.prior[k] - ts.truth[k], axis=-1)
        metrics[split] = {"samples": int(k.sum()), "mean_error_cm": float(err.mean()), "p95_error_cm": float(np.percentile(err, 95)),
                          "skinning_mean_error_cm": float(prior.mean())}
        if model.config.fabric:  # each fabric's share of the split
            metrics[split]["by_fabric"] = {f: {"samples": int((labels[k] == f).sum()),
                                               "mean_error_cm": float(err[labels[k] == f].mean())}
                                           for f in sorted(set(labels[k].tolist()))}
    return {"garment": model.garment, "sizes": model.sizes, "trained": timestamp(), "data": str(data_dir),
            "manifest": json.loads(data.manifest.to_json()), "samples": {s: int((ts.split == s).sum()) for s in sorted(set(ts.split.tolist()))},
            "split": data.manifest.split, "train_config": config.to_dict(), "best_epoch": model.card.get("epoch"),
            "epochs": state["epoch"], "train_wall_s_this_run": wall_s, "metrics": metrics,
            "history": state["history"][-200:]}


def _merged_lines(manifest: dict) -> list[str]:
    """Card lines for the refined sets trained on too (self-correction)."""
    lines = []
    for m in manifest.get("notes", {}).get("merged", []):
        truth = m["spec"].get("truth", {})
        lines.append(f"- Plus {m['folder']}: {m['count']} drapes of bodies drawn with seed {m['seed']}, ground truth "
                     f"{truth.get('method', 'simulated')}" + (f" (refined predictions of model {truth['model_sha1']})"
                                                               if "model_sha1" in truth else "") + "; they train only.")
    return lines


def _fabric_words(spec: dict) -> str:
    if not spec.get("fabrics"):
        return f"fabric {spec['fabric']} (Wang et al. 2011, measured)"
    mixed = f"; {spec['fabric_mix']:.0%} of the drapes blended between two of them" if spec.get("fabric_mix") else ""
    return (f"the fabric drawn per drape from {len(spec['fabrics'])} measured ones (Wang et al. 2011: "
            f"{', '.join(spec['fabrics'])}{mixed})")


def card_markdown(card: dict) -> str:
    """The model card for people: what the model is, its data, its split and its numbers."""
    spec = card["manifest"]["spec"]
    r = spec["ranges"]
    lines = [f"# Learned draping model: {card['garment']}, sizes {', '.join(card['sizes'])}", "",
             "Predicts the drape `tryon drape` simulates for an A-posed Anny body, in milliseconds on a CPU "
             "(docs/LEARNED.md). Trained " + str(card["trained"]) + ".", "",
             "## Data", "",
             f"- {sum(card['samples'].values())} simulated drapes (`tryon dataset drape`, seed {card['manifest']['seed']}, "
             f"software {card['manifest']['software_version']}): {spec['garment']} in {', '.join(spec['sizes'])}, "
             f"{_fabric_words(spec)}, {spec['edge_length'] * 100:.1f} cm edges.",
             f"- Bodies: Anny (Apache-2.0, CC0 data), genders {', '.join(r['genders'])}, BMI uniform in "
             f"{r['bmi'][0]:g}-{r['bmi'][1]:g}, stature uniform per gender "
             + ", ".join(f"{g} {h[0]:g}-{h[1]:g} cm" for g, h in r["height_cm"].items()) + f", age {r['age_years'][0]:g}-{r['age_years'][1]:g}.",
             f"- Split by body ({card['split']['rule']}): " + ", ".join(f"{k} {v}" for k, v in sorted(card["samples"].items()))
             + f"; extrapolation = BMI >= {card['split']['extrapolation_bmi']:g}. Selected on: {card.get('selected_on', 'val')}.",
             *_merged_lines(card["manifest"]),
             "", "## Metrics (vertex error against the simulated drape)", "",
             "| split | samples | mean cm | p95 cm | skinning baseline mean cm |", "|---|---:|---:|---:|---:|"]
    for split, m in sorted(card["metrics"].items()):
        lines.append(f"| {split} | {m['samples']} | {m['mean_error_cm']:.2f} | {m['p95_error_cm']:.2f} | {m['skinning_mean_error_cm']:.2f} |")
    by_fabric = {split: m["by_fabric"] for split, m in sorted(card["metrics"].items()) if "by_fabric" in m}
    if by_fabric:
        lines += ["", "Mean vertex error (cm) per fabric (drapes in brackets):", "",
                  "| fabric | " + " | ".join(by_fabric) + " |", "|---|" + "---:|" * len(by_fabric)]
        for f in sorted({f for per in by_fabric.values() for f in per}):
            cells = [f"{per[f]['mean_error_cm']:.2f} ({per[f]['samples']})" if f in per else "" for per in by_fabric.values()]
            lines.append(f"| {f} | " + " | ".join(cells) + " |")
    if card.get("metrics_note"):
        lines += ["", card["metrics_note"]]
    t = card["train_config"]
    lines += ["", "## Training", "",
              f"{card['epochs']} epochs (best {card['best_epoch']}), batch {t['batch']}, learning rate {t['lr']}, seed {t['seed']}; "
              f"loss weights {t['weights']}.", "",
              "## Limits", "",
              "Bodies outside the ranges above, other poses than the A-pose, other fabrics and sizes are outside what the "
              "model has seen: simulate those (`--method simulate`), or refine the prediction (`--refine`).", ""]
    return "\n".join(lines)
