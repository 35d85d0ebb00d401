"""`tryon train kdsm --data POSES --method METHOD --out DIR`: the pixel network for one
method on a pose dataset.

Every pose of the dataset's sequences becomes an example: the pose's bone transforms in,
the method's per-vertex target out (`KdsmRig.target`, computed once and cached in
`DIR/cache`). Inputs and targets are standardised on the training split. Adam at 1e-3
(Jin et al.), L2 loss at the vertices, a fixed seed, a checkpoint every epoch (the same
command resumes), the epoch with the lowest validation error kept. The model card holds
the data manifest and, per split, the mean and spread of the per-frame vertex error of the
rebuilt garment (cm), as the paper's Table 2 reports them.
"""

from __future__ import annotations

import hashlib
import json
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from tryon.errors import TryonError
from tryon.io.atomic import atomic_write
from tryon.kdsm.model import KdsmModel, pose_features
from tryon.kdsm.network import PanelAtlas
from tryon.kdsm.rig import HYBRID_SMOOTHING, METHODS, SMOOTHING_BEFORE_SETTING, KdsmRig

CHECKPOINT = "checkpoint.pt"
SPLITS = ("train", "val", "test")
SCHEDULES = ("constant", "cosine")
# What training did before each setting existed: checkpoints and cards without it mean this.
BEFORE_SETTING = {"schedule": "constant", "mirror": False, "smoothing": SMOOTHING_BEFORE_SETTING}


@dataclass
class KdsmTrainConfig:
    method: str = "kdsm-hybrid"
    epochs: int = 40
    batch: int = 16
    lr: float = 1e-3
    seed: int = 0
    cell: float = 0.02
    schedule: str = "cosine"    # the learning rate over the epochs: "constant" (Jin et al.) or cosine decay to 5 %
    mirror: bool = False        # add each training pose's left-right mirror image (tryon.kdsm.mirror)
    smoothing: float = HYBRID_SMOOTHING   # screened-Poisson strength of the hybrid's d (kdsm-hybrid only)

    def validate(self) -> None:
        if self.method not in METHODS or self.method == "skinning":
            raise TryonError(f"--method {self.method!r}: train one of {', '.join(m for m in METHODS if m != 'skinning')}")
        if not (1 <= self.epochs <= 10_000 and 1 <= self.batch <= 1024 and 0 < self.lr < 1 and self.seed >= 0):
            raise TryonError("epochs 1-10,000, batch 1-1,024, a learning rate in (0, 1) and a seed >= 0")
        if not 0.005 <= self.cell <= 0.1:
            raise TryonError(f"--cell {self.cell} m is outside 0.005-0.1 m")
        if not 0.0 <= self.smoothing <= 100.0:
            raise TryonError(f"--smoothing {self.smoothing} is outside 0-100")
        if self.method != "kdsm-hybrid" and self.smoothing != HYBRID_SMOOTHING:
            raise TryonError(f"--smoothing applies to kdsm-hybrid's targets only, not {self.method}'s")
        if self.schedule not in SCHEDULES:
            raise TryonError(f"--schedule {self.schedule!r}: one of {', '.join(SCHEDULES)}")

    def learning_rate(self, epoch: int) -> float:
        """The rate for (0-based) `epoch`: a function of the epoch alone, so a resumed run follows it exactly."""
        if self.schedule == "constant":
            return self.lr
        return float(self.lr * (0.05 + 0.95 * 0.5 * (1.0 + np.cos(np.pi * epoch / self.epochs))))


def examples(data, rig: KdsmRig, method: str, cache: Path | None = None, progress: bool = True,
             mirror: bool = False, smoothing: float = HYBRID_SMOOTHING) -> dict[str, np.ndarray]:
    """Every ok sequence's poses: per-bone axis-angle [N,J,3], targets [N,n,3], cloth
    [N,n,3], split [N], sequence [N], mirrored [N]; with `mirror`, each training sequence
    also in its left-right mirror image. Targets are cached per sequence (one file each,
    in a folder keyed by the dataset's settings, the rest drape, the method and the
    volume, and for the hybrid its smoothing), so a dataset that grew only computes its new
    sequences."""
    rows = data.rows()
    key = hashlib.sha1(json.dumps(data.manifest.spec, sort_keys=True).encode() + rig.x0.tobytes() + method.encode()
                       + str(rig.volume.cell).encode()
                       + (f"smoothing={float(smoothing)!r}".encode() if method == "kdsm-hybrid" else b"")).hexdigest()[:16]
    folder = None if cache is None else cache / f"{method}-{key}"
    mirror_map = None
    if mirror:
        from tryon.kdsm.mirror import MirrorMap

        g = data.rest.garment
        mirror_map = MirrorMap.build(g.vertices, g.faces, g.corner_uv, g.face_panel)
    parts: dict[str, list] = {k: [] for k in ("pose", "target", "x", "split", "sequence", "mirrored")}
    for r in tqdm(rows, desc=f"{method} targets", unit="sequence", disable=not progress, leave=False):
        unit, split = int(data.arrays["unit"][r]), str(data.arrays["split"][r])
        poses, xs = data.arrays["pose"][r].astype(np.float64), data.arrays["x"][r].astype(np.float64)
        versions = [(False, poses, xs)]
        if mirror_map is not None and split == "train":
            from tryon.kdsm.mirror import mirror_pose

            versions.append((True, np.stack([mirror_pose(p, rig.shape.bone_labels) for p in poses]),
                             np.stack([mirror_map.cloth(x) for x in xs])))
        for mirrored, P, X in versions:
            path = None if folder is None else folder / f"{unit:07d}{'m' if mirrored else ''}.npz"
            parts["target"].append(_cached_targets(path, rig, method, X, P, smoothing))
            parts["pose"].append(P.astype(np.float32))
            parts["x"].append(X.astype(np.float32))
            parts["split"] += [split] * len(P)
            parts["sequence"] += [unit] * len(P)
            parts["mirrored"] += [mirrored] * len(P)
    out = {k: np.concatenate(parts[k]) for k in ("pose", "target", "x")}
    out.update({k: np.asarray(parts[k]) for k in ("split", "sequence", "mirrored")})
    return out


def _cached_targets(path: Path | None, rig: KdsmRig, method: str, xs: np.ndarray, poses: np.ndarray,
                    smoothing: float) -> np.ndarray:
    if path is not None and path.exists():
        with np.load(path) as z:
            return z["target"]
    target = np.stack([rig.target(method, x, rig.transforms(p), smoothing=smoothing)
                       for x, p in zip(xs, poses)]).astype(np.float32)
    if path is not None:
        path.parent.mkdir(parents=True, exist_ok=True)
        with atomic_write(path, "wb") as fh:
            np.savez(fh, target=target)
    return target


def moving_bones(poses: np.ndarray, tol: float = 1e-6) -> np.ndarray:
    """Bones whose rotation varies over the poses (per-bone axis-angle [N,J,3])."""
    return np.flatnonzero(np.asarray(poses).std(0).max(1) > tol)


def train_kdsm(data_dir: str | Path, out: str | Path, config: KdsmTrainConfig | None = None, progress: bool = True,
               force: bool = False, max_epochs_this_run: int | None = None) -> KdsmModel | None:
    """Train (or resume) the network of `config.method` on the pose dataset in `data_dir`;
    `max_epochs_this_run` stops early (as an interruption would; returns None then)."""
    from tryon.dataset.poses import load_pose_dataset
    from tryon.io.atomic import claim_work_dir, is_owned

    config = config or KdsmTrainConfig()
    config.validate()
    out = Path(out)
    claim_work_dir(out, resume=(out / CHECKPOINT).exists() and is_owned(out), force=force)
    ckpt = out / CHECKPOINT
    saved = torch.load(ckpt, weights_only=True) if ckpt.exists() else None
    if saved is not None:   # before any target is computed: say which setting differs
        _check_resumable(ckpt, json.loads(saved["config"]), config)
    data = load_pose_dataset(data_dir)
    g = data.rest.garment
    rig = KdsmRig.build(g.vertices, g.faces, data.rest.shape(), cell=config.cell)
    ex = examples(data, rig, config.method, out / "cache", progress, mirror=config.mirror, smoothing=config.smoothing)
    train = np.flatnonzero(ex["split"] == "train")
    val = np.flatnonzero(ex["split"] == "val")
    selected_on = "val" if len(val) else "train"
    if len(train) < 2:
        raise TryonError(f"{data_dir} has {len(train)} training poses; make more with tryon dataset poses")
    val = val if len(val) else train
    bones = moving_bones(ex["pose"][train])
    feats = np.stack([pose_features(p, bones) for p in ex["pose"]])
    fm, fs = feats[train].mean(0), np.maximum(feats[train].std(0), 1e-6)
    tm, ts = ex["target"][train].reshape(-1, 3).mean(0), np.maximum(ex["target"][train].reshape(-1, 3).std(0), 1e-6)
    atlas = PanelAtlas.from_garment(g.faces, g.corner_uv, g.face_panel)
    model = KdsmModel(config.method, rig, atlas, bones, fm, fs, tm.astype(np.float64), ts.astype(np.float64))
    F = torch.from_numpy(((feats - fm) / fs).astype(np.float32))
    Y = torch.from_numpy(((ex["target"] - tm) / ts).astype(np.float32))
    torch.manual_seed(config.seed)
    net = model.build_net().train()
    opt = torch.optim.Adam(net.parameters(), lr=config.lr)
    state = {"epoch": 0, "best_val": float("inf"), "history": []}
    data_key = hashlib.sha1(feats.tobytes()[:1_000_000] + ex["target"][:64].tobytes()).hexdigest()[:16]
    if saved is not None:
        if saved["data"] != data_key:
            raise TryonError(f"{ckpt} was made with other data; use another --out or remove it")
        net.load_state_dict(saved["net"])
        opt.load_state_dict(saved["opt"])
        state = json.loads(saved["state"])
        torch.set_rng_state(saved["rng"])
    t0 = time.perf_counter()
    run = 0
    while state["epoch"] < config.epochs:
        if max_epochs_this_run is not None and run >= max_epochs_this_run:
            return None
        run += 1
        net.train()
        for group in opt.param_groups:
            group["lr"] = config.learning_rate(state["epoch"])
        order = train[np.random.default_rng([config.seed, state["epoch"]]).permutation(len(train))]
        total = 0.0
        bar = tqdm(range(0, len(order), config.batch), desc=f"epoch {state['epoch'] + 1}/{config.epochs}",
                   disable=not progress, leave=False)
        for s in bar:
            idx = torch.from_numpy(order[s:s + config.batch])
            if len(idx) < 2:      # batch norm needs two
                continue
            loss = ((atlas.sample(net(F[idx])) - Y[idx]) ** 2).mean()
            opt.zero_grad()
            loss.backward()
            opt.step()
            total += float(loss.detach()) * len(idx)
        model.weights = {k: v.detach().numpy().copy() for k, v in net.state_dict().items()}
        val_err = float(frame_errors(model, ex, val, net).mean())
        if not np.isfinite(val_err) or not np.isfinite(total):
            raise TryonError(f"training diverged in epoch {state['epoch'] + 1}; lower --lr")
        state["epoch"] += 1
        state["history"].append({"epoch": state["epoch"], "train_loss": total / len(order), "val_mean_error_cm": val_err})
        if val_err < state["best_val"]:
            state["best_val"] = val_err
            model.card = {"config": asdict(config)}   # until the full card: what it was trained with
            model.save(out / "best.npz")
        torch.save({"net": net.state_dict(), "opt": opt.state_dict(), "rng": torch.get_rng_state(), "state": json.dumps(state),
                    "config": json.dumps(asdict(config), sort_keys=True), "data": data_key}, out / (CHECKPOINT + ".tmp"))
        (out / (CHECKPOINT + ".tmp")).replace(ckpt)
        if progress:
            print(f"epoch {state['epoch']}: train loss {total / len(order):.4f}, val mean error {val_err:.3f} cm", flush=True)
    best = KdsmModel.load(out / "best.npz")
    best.card = model_card(data, Path(data_dir), best, ex, config, state, selected_on, time.perf_counter() - t0)
    best.save(out / "model.npz")
    with atomic_write(out / "model_card.json") as fh:
        json.dump(best.card, fh, indent=1)
    with atomic_write(out / "MODEL_CARD.md") as fh:
        fh.write(card_markdown(best.card))
    return best


def card_markdown(card: dict) -> str:
    """The model card as a short page: data, split, settings and the error per split."""
    spec = card["manifest"]["spec"]
    lines = [f"# KDSM model: {card['method']}", "",
             f"- Data: `tryon dataset poses`, {spec['garment']} {spec['size']} on the {spec['gender']} fit model, "
             f"{spec['fabric']}, {spec['edge_length']} m edges, sequences of {spec['frames']} poses at {spec['fps']:g} fps"
             f"{_recording_note(spec)} (seed {card['manifest']['seed']}, generator version "
             f"{card['manifest']['generator_version']}).",
             f"- Split: {card['manifest']['split']['rule']}.",
             f"- Training: {card['epochs']} epochs, batch {card['config']['batch']}, Adam {card['config']['lr']} "
             f"({_resumed_config(card['config'])['schedule']}), "
             f"{'training poses and their mirror images, ' if card['config'].get('mirror') else ''}"
             f"{_smoothing_note(card)}seed "
             f"{card['config']['seed']}, volume cell {card['config']['cell']} m, {card['bones']} moving bones as input; "
             f"selected on {card['selected_on']}; {card['training_s'] / 60:.0f} min here.", "",
             "| split | sequences | frames | mean error (cm) | std over frames (cm) |", "|---|---:|---:|---:|---:|"]
    for split, m in card["metrics"].items():
        lines.append(f"| {split} | {m['sequences']} | {m['frames']} | {m['mean_error_cm']:.3f} | {m['std_error_cm']:.3f} |")
    return "\n".join(lines) + "\n"


def _recording_note(spec: dict) -> str:
    if spec.get("from_rest"):
        return f", each pose simulated on its own from the rest drape and held {spec['settle']:g} s (--from-rest)"
    if spec.get("settle"):
        return f", each pose held {spec['settle']:g} s"
    return ""


def _resumed_config(saved: dict) -> dict:
    """A checkpoint's (or card's) settings, completed for settings added since it was made:
    each takes the value training had before it existed (`BEFORE_SETTING`). Smoothing
    means nothing to methods other than the hybrid: theirs is the default, whatever was saved."""
    config = {**asdict(KdsmTrainConfig()), **BEFORE_SETTING, **saved}
    if config["method"] != "kdsm-hybrid":
        config["smoothing"] = HYBRID_SMOOTHING
    return config


def _check_resumable(ckpt: Path, saved: dict, config: KdsmTrainConfig) -> None:
    was, asked = _resumed_config(saved), asdict(config)
    differ = [f"{k}: {was.get(k)!r} there, {v!r} asked" for k, v in asked.items() if was.get(k) != v]
    if differ:
        raise TryonError(f"{ckpt} was made with other settings ({'; '.join(differ)}); pass those to resume it, "
                         "or use another --out")


def _smoothing_note(card: dict) -> str:
    if card["method"] != "kdsm-hybrid":
        return ""
    return f"targets smoothed with strength {_resumed_config(card['config'])['smoothing']:g}, "


def frame_errors(model: KdsmModel, ex: dict, rows: np.ndarray, net=None, batch: int = 32) -> np.ndarray:
    """Per-frame mean vertex error (cm) of the rebuilt garment over `rows`."""
    net = net or model.build_net()
    net.eval()
    rig = model.rig
    out = []
    for s in range(0, len(rows), batch):
        idx = rows[s:s + batch]
        Gs = [rig.transforms(p) for p in ex["pose"][idx]]
        if model.method == "skinning":
            pred = [rig.skinned(G) for G in Gs]
        else:
            vals = model.values(net, np.stack([model.features(p) for p in ex["pose"][idx]]))
            pred = [rig.positions(model.method, v, G) for v, G in zip(vals, Gs)]
        out.extend(100.0 * np.linalg.norm(np.stack(pred) - ex["x"][idx], axis=-1).mean(1))
    return np.asarray(out)


def model_card(data, data_dir: Path, model: KdsmModel, ex: dict, config: KdsmTrainConfig, state: dict, selected_on: str,
               seconds: float) -> dict:
    metrics = {}
    for split in SPLITS:
        rows = np.flatnonzero((ex["split"] == split) & ~ex["mirrored"])   # the simulated poses only
        if len(rows):
            e = frame_errors(model, ex, rows)
            metrics[split] = {"frames": int(len(rows)), "sequences": int(len(np.unique(ex["sequence"][rows]))),
                              "mean_error_cm": float(e.mean()), "std_error_cm": float(e.std())}
    return {"kind": "kdsm", "method": config.method, "data": str(data_dir), "manifest": json.loads(data.manifest.to_json()),
            "config": asdict(config), "bones": len(model.bones), "epochs": state["epoch"], "selected_on": selected_on,
            "best_val_mean_error_cm": state["best_val"], "metrics": metrics, "history": state["history"],
            "training_s": seconds, "trained": time.strftime("%Y-%m-%dT%H:%M:%S%z")}
