"""`tryon train body-photos`: the body-from-photos regression on a photo dataset
(`tryon dataset bodies`).

Fixed seed, a checkpoint every epoch (the same command resumes), the best model on the
validation people kept, and a model card with the data's manifest and the error per
number of views against the body from stature, weight and gender alone.
"""

from __future__ import annotations

import json
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from tryon.dataset.photos import KIND
from tryon.dataset.store import DatasetError, Manifest, ShardStore
from tryon.errors import TryonError
from tryon.io.atomic import atomic_write
from tryon.learn.body_photos import (WEIGHT_TAPES, BodyFromViews, HeightWeightBaseline, RegressorConfig,
                                     WeightModel, body_frame_joints, condition, load_model, project, save_model,
                                     silhouette_profile, unpack_masks)

CHECKPOINT = "checkpoint.pt"
GIRTHS = ("chest", "waist_navel", "hip")
# views in the order a shopper would give them: 1 = front, 2 = front + left, 4 = front, back, left, right
VIEW_ORDER = ("front", "left", "back", "right", "random")


@dataclass
class BodyTrainConfig:
    epochs: int = 60
    batch: int = 16
    lr: float = 1e-3
    seed: int = 0
    no_weight_fraction: float = 0.25  # training people seen without their weight (a shopper may not give it)

    def to_dict(self) -> dict:
        return asdict(self)


@dataclass
class PhotoTensors:
    """A photo dataset's people, as the network reads them (numpy, row = person)."""

    masks: np.ndarray       # [N,V,1,C,C] uint8
    keypoints: np.ndarray   # [N,V,33,3] float32
    profile: np.ndarray     # [N,V,P] float32 (silhouette_profile)
    present: np.ndarray     # [N,V] float32
    height: np.ndarray
    weight: np.ndarray
    gender: np.ndarray
    age: np.ndarray
    tapes: np.ndarray       # [N,M] cm
    shape: np.ndarray       # [N,S]
    joints: np.ndarray      # [N,J,3] body frame
    joints_2d: np.ndarray   # [N,V,J,2] crop units
    split: np.ndarray
    views: list[str]
    tape_names: list[str]

    def rows(self, split: str) -> np.ndarray:
        return np.nonzero(self.split == split)[0]

    def girths(self, rows: np.ndarray) -> np.ndarray:
        return self.tapes[rows][:, [self.tape_names.index(n) for n in WEIGHT_TAPES]]


@dataclass
class Standards:
    """What the targets are measured against, fitted on the training people only."""

    baseline: HeightWeightBaseline
    weight: WeightModel
    shape_mean: np.ndarray
    shape_sd: np.ndarray

    @classmethod
    def fit(cls, t: PhotoTensors, train: np.ndarray) -> "Standards":
        return cls(HeightWeightBaseline.fit(t.height[train], t.weight[train], t.gender[train], t.tapes[train]),
                   WeightModel.fit(t.height[train], t.gender[train], t.weight[train], t.girths(train)),
                   t.shape[train].mean(0), t.shape[train].std(0) + 1e-3)

    def weights(self, t: PhotoTensors, idx: np.ndarray, given: np.ndarray) -> np.ndarray:
        """The weight the network is told: the person's own, or the guess from stature."""
        return np.where(given, t.weight[idx], self.weight.from_height(t.height[idx], t.gender[idx]))


def load_photo_tensors(folder: str | Path) -> tuple[Manifest, PhotoTensors]:
    folder = Path(folder)
    manifest = Manifest.read(folder)
    if manifest.kind != KIND:
        raise DatasetError(f"{folder} holds a {manifest.kind!r} dataset, not {KIND} (make one with tryon dataset bodies)")
    a = ShardStore(folder, manifest).load()
    if not len(a.get("gender", [])):
        raise DatasetError(f"{folder} has no finished people yet; run tryon dataset bodies --out {folder} again")
    spec = manifest.spec
    crop = int(spec["crop_px"])
    ok = np.asarray(a["ok"], bool)
    masks = (unpack_masks(a["view_mask_bits"][ok], crop) > 0.5).astype(np.uint8)
    kp = np.concatenate([a["view_keypoints"][ok].astype(np.float32),
                         a["view_visibility"][ok].astype(np.float32)[..., None]], -1)
    t = PhotoTensors(masks=masks, keypoints=kp, profile=silhouette_profile(masks[:, :, 0], kp), present=a["view_found"][ok].astype(np.float32),
                     height=a["height_cm"][ok].astype(np.float64), weight=a["weight_kg"][ok].astype(np.float64),
                     gender=a["gender"][ok].astype(np.float64), age=a["age"][ok].astype(np.float64), tapes=a["tapes_cm"][ok].astype(np.float64),
                     shape=a["shape_params"][ok].astype(np.float32),
                     joints=body_frame_joints(a["joints_3d"][ok].astype(np.float64), a["height_cm"][ok], spec["joints"]),
                     joints_2d=a["view_joints_2d"][ok].astype(np.float32), split=np.asarray(a["split"][ok]).astype(str),
                     views=list(spec["views"]), tape_names=list(spec["tapes"]))
    return manifest, t


def _batch(t: PhotoTensors, idx: np.ndarray, std: Standards, view_sets: list[list[int]],
           weight_given: np.ndarray) -> dict[str, torch.Tensor]:
    """Tensors of people `idx`, each seen through its own list of views (in that order),
    told their weight where `weight_given`."""
    V = max(len(v) for v in view_sets)
    B = len(idx)
    C = t.masks.shape[-1]
    masks = np.zeros((B, V, 1, C, C), np.float32)
    kp = np.zeros((B, V, 33, 3), np.float32)
    prof = np.zeros((B, V, t.profile.shape[-1]), np.float32)
    present = np.zeros((B, V), np.float32)
    j2d = np.zeros((B, V, t.joints_2d.shape[2], 2), np.float32)
    for b, (r, views) in enumerate(zip(idx, view_sets)):
        for k, v in enumerate(views):
            masks[b, k] = t.masks[r, v]
            kp[b, k] = t.keypoints[r, v]
            prof[b, k] = t.profile[r, v]
            present[b, k] = t.present[r, v]
            j2d[b, k] = t.joints_2d[r, v]
    w = std.weights(t, idx, weight_given)
    resid = std.baseline.residual(t.height[idx], w, t.gender[idx], t.tapes[idx])
    return {"mask": torch.from_numpy(masks), "keypoints": torch.from_numpy(kp), "profile": torch.from_numpy(prof),
            "present": torch.from_numpy(present),
            "cond": torch.from_numpy(condition(t.height[idx], w, t.gender[idx], weight_given)),
            "residual": torch.from_numpy(resid.astype(np.float32)),
            "shape": torch.from_numpy(((t.shape[idx] - std.shape_mean) / std.shape_sd).astype(np.float32)),
            "joints": torch.from_numpy(t.joints[idx]), "joints_2d": torch.from_numpy(j2d)}


def _loss(out: dict, b: dict) -> tuple[torch.Tensor, dict[str, float]]:
    err = out["residual"] - b["residual"]
    log_sd = out["log_sd"].clamp(-4.0, 3.0)
    nll = (0.5 * (err / log_sd.exp()) ** 2 + log_sd).mean()
    mse = (err ** 2).mean()
    shape = ((out["shape"] - b["shape"]) ** 2).mean()
    joints = ((out["joints"] - b["joints"]) ** 2).sum(-1).mean()
    proj = project(out["joints"], out["camera"])
    on = b["present"][..., None]
    reproj = (((proj - b["joints_2d"]) ** 2).sum(-1) * on).sum() / (on.sum() * proj.shape[2]).clamp(min=1.0)
    total = nll + 0.5 * mse + 0.1 * shape + 10.0 * joints + 10.0 * reproj
    parts = {"nll": nll, "mse": mse, "shape": shape, "joints": joints, "reproj": reproj}
    return total, {k: float(v.detach()) for k, v in parts.items()}


def view_subsets(t: PhotoTensors) -> dict[int, list[int]]:
    """The views a shopper gives: 1 (front), 2 (front, left), 4 (front, back, left, right)."""
    order = [t.views.index(v) for v in VIEW_ORDER if v in t.views]
    return {n: order[:n] for n in (1, 2, 4) if n <= len(order)}


def predict(net: BodyFromViews, t: PhotoTensors, rows: np.ndarray, std: Standards, views: list[int],
            weight_given: bool) -> np.ndarray:
    """Every tape (cm) of people `rows` seen through `views`."""
    preds = []
    with torch.no_grad():
        for s in range(0, len(rows), 64):
            idx = rows[s:s + 64]
            given = np.full(len(idx), weight_given)
            b = _batch(t, idx, std, [views] * len(idx), given)
            o = net(b["mask"], b["keypoints"], b["profile"], b["present"], b["cond"])
            preds.append(std.baseline.measurements(t.height[idx], std.weights(t, idx, given), t.gender[idx],
                                                   o["residual"].numpy().astype(np.float64)))
    return np.concatenate(preds)


def evaluate(net: BodyFromViews, t: PhotoTensors, rows: np.ndarray, std: Standards) -> dict:
    """Mean relative error (%) of every tape per number of views, with and without the
    weight, and of the baseline from stature, weight and gender."""
    net.eval()
    out: dict = {"people": int(len(rows))}
    truth = t.tapes[rows]
    out["height-weight"] = _errors(std.baseline.measurements(t.height[rows], t.weight[rows], t.gender[rows],
                                                             np.zeros_like(truth)), truth, t.tape_names)
    for n, views in view_subsets(t).items():
        out[f"views-{n}"] = _errors(predict(net, t, rows, std, views, True), truth, t.tape_names)
    for n, views in view_subsets(t).items():
        out[f"views-{n}-no-weight"] = _errors(predict(net, t, rows, std, views, False), truth, t.tape_names)
    return out


def _errors(pred: np.ndarray, truth: np.ndarray, names: list[str]) -> dict:
    rel = 100.0 * np.abs(pred - truth) / truth
    per = {n: round(float(rel[:, i].mean()), 3) for i, n in enumerate(names)}
    return {"per_measurement_pct": per, "girths_pct": round(float(np.mean([per[g] for g in GIRTHS])), 3)}


def train_body_photos(data: str | Path, out: str | Path, config: BodyTrainConfig | None = None, progress: bool = True,
                      force: bool = False, max_epochs_this_run: int | None = None) -> Path:
    """Train (or resume) the regression on the dataset in `data`; writes `out/model.npz`,
    `out/model_card.json` and `MODEL_CARD.md`."""
    from tryon.io.atomic import claim_work_dir, is_owned

    config = config or BodyTrainConfig()
    out = Path(out)
    claim_work_dir(out, resume=(out / CHECKPOINT).exists() and is_owned(out), force=force)
    manifest, t = load_photo_tensors(data)
    train, val = t.rows("train"), t.rows("val")
    if len(train) < 4:
        raise TryonError(f"{data} has {len(train)} training people; make more with tryon dataset bodies")
    if len(val) == 0:
        val = train
    std = Standards.fit(t, train)
    torch.manual_seed(config.seed)
    cfg = RegressorConfig(crop=t.masks.shape[-1], measurements=t.tapes.shape[1], shape=t.shape.shape[1],
                          joints=t.joints.shape[1])
    net = BodyFromViews(cfg)
    net.encoder.standardise_profile(t.profile[train][t.present[train] > 0])
    opt = torch.optim.Adam(net.parameters(), lr=config.lr)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, T_max=config.epochs, eta_min=config.lr * 0.05)
    state = {"epoch": 0, "best_val": float("inf"), "history": []}
    key = json.dumps({"config": config.to_dict(), "people": int(len(t.split)), "seed": manifest.seed}, sort_keys=True)
    ckpt = out / CHECKPOINT
    if ckpt.exists():
        saved = torch.load(ckpt, weights_only=True)
        if saved["key"] != key:
            raise TryonError(f"{ckpt} was made with other settings or data; use another --out or remove it")
        net.load_state_dict(saved["net"])
        opt.load_state_dict(saved["opt"])
        sched.load_state_dict(saved["sched"])
        state = json.loads(saved["state"])
    V = len(t.views)
    t0 = time.perf_counter()
    runs = 0
    while state["epoch"] < config.epochs and (max_epochs_this_run is None or runs < max_epochs_this_run):
        net.train()
        rng = np.random.default_rng([config.seed, state["epoch"]])  # resumes exactly
        order = rng.permutation(train)
        sums: dict[str, float] = {}
        bar = tqdm(range(0, len(order), config.batch), desc=f"epoch {state['epoch'] + 1}/{config.epochs}",
                   disable=not progress, leave=False)
        for s in bar:
            idx = order[s:s + config.batch]
            # any number of views, in any order: 1 to all, drawn per person
            sets = [list(rng.permutation(V)[:rng.integers(1, V + 1)]) for _ in idx]
            given = rng.random(len(idx)) >= config.no_weight_fraction
            b = _batch(t, idx, std, sets, given)
            o = net(b["mask"], b["keypoints"], b["profile"], b["present"], b["cond"])
            loss, parts = _loss(o, b)
            opt.zero_grad()
            loss.backward()
            torch.nn.utils.clip_grad_norm_(net.parameters(), 5.0)
            opt.step()
            for k, v in parts.items():
                sums[k] = sums.get(k, 0.0) + v * len(idx)
            bar.set_postfix(mse=f"{parts['mse']:.3f}")
        sched.step()
        ev = evaluate(net, t, val, std)
        score = max(v["girths_pct"] for k, v in ev.items() if k.startswith("views-") and not k.endswith("no-weight"))
        if not np.isfinite(score):
            raise TryonError(f"training diverged in epoch {state['epoch'] + 1}; lower --lr")
        state["epoch"] += 1
        runs += 1
        state["history"].append({"epoch": state["epoch"], **{k: v / len(order) for k, v in sums.items()},
                                 **{f"val_{k}_girths_pct": v["girths_pct"] for k, v in ev.items() if k != "people"}})
        if score < state["best_val"]:
            state["best_val"] = score
            save_model(out / "best.npz", net, std.baseline, std.weight,
                       {"epoch": state["epoch"], "shape_mean": std.shape_mean.tolist(),
                        "shape_sd": std.shape_sd.tolist(), "tapes": t.tape_names, "views": t.views})
        torch.save({"net": net.state_dict(), "opt": opt.state_dict(), "sched": sched.state_dict(),
                    "state": json.dumps(state), "key": key}, out / (CHECKPOINT + ".tmp"))
        (out / (CHECKPOINT + ".tmp")).replace(ckpt)
        if progress:
            print(f"epoch {state['epoch']}: " + ", ".join(f"{k} {v['girths_pct']:.2f} %" for k, v in ev.items()
                                                          if k != "people"), flush=True)
    best = load_model(out / "best.npz")
    card = best.card
    test = t.rows("test")
    card.update({"data": str(data), "manifest": {"kind": manifest.kind, "seed": manifest.seed,
                                                 "generator_version": manifest.generator_version,
                                                 "software_version": manifest.software_version,
                                                 "spec": manifest.spec},
                 "split": {s: int(len(t.rows(s))) for s in ("train", "val", "test")}, "train": config.to_dict(),
                 "history": state["history"], "wall_s": time.perf_counter() - t0,
                 "test": evaluate(best.net, t, test, std) if len(test) else None})
    save_model(out / "model.npz", best.net, best.baseline, best.weight, card)
    with atomic_write(out / "model_card.json") as fh:
        json.dump(card, fh, indent=1)
    with atomic_write(out / "MODEL_CARD.md") as fh:
        fh.write(card_markdown(card))
    return out / "model.npz"


def card_markdown(card: dict) -> str:
    lines = ["# Body from photos: model card", "",
             f"Data: `{card['data']}` ({card['manifest']['kind']}, seed {card['manifest']['seed']}, "
             f"generator {card['manifest']['generator_version']}); people per split: {card['split']}.",
             f"Training: {card['train']}; best epoch {card['epoch']}.", ""]
    test = card.get("test")
    if test:
        lines += [f"Test people: {test['people']}. Mean relative error (%) of the measurements the network reads (`height-weight`: the least-squares regression on stature, weight and gender it reads them as residuals from):", "",
                  "| input | chest, waist, hip | " + " | ".join(card["tapes"]) + " |",
                  "|---|---|" + "---|" * len(card["tapes"])]
        for k, v in test.items():
            if k == "people":
                continue
            lines.append(f"| {k} | {v['girths_pct']:.2f} | "
                         + " | ".join(f"{v['per_measurement_pct'][n]:.2f}" for n in card["tapes"]) + " |")
    return "\n".join(lines) + "\n"
