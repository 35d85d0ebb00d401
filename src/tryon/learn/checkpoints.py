"""What every `tryon train ...` loop shares: a model's weights in an npz with JSON fields
beside them (the shipped form: no pickle), and the epoch loop that checkpoints every
epoch, resumes from the checkpoint with the same shuffles, and keeps the best model on
validation."""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np
import torch
from tqdm import tqdm

from tryon.errors import TryonError
from tryon.io.atomic import atomic_write

CHECKPOINT = "checkpoint.pt"


def save_weights(path: Path, model: torch.nn.Module, **fields) -> Path:
    """`model`'s parameters as `param/NAME` arrays, each keyword as a JSON string."""
    arrays = {f"param/{k}": v.detach().numpy() for k, v in model.state_dict().items()}
    with atomic_write(path, "wb") as fh:
        np.savez(fh, **{k: np.asarray(json.dumps(v)) for k, v in fields.items()}, **arrays)
    return path


def load_weights(path: str | Path) -> tuple[dict[str, torch.Tensor], dict]:
    """The parameters and the JSON fields that `save_weights` wrote."""
    try:
        with np.load(path, allow_pickle=False) as z:
            state = {k[len("param/"):]: torch.from_numpy(z[k]) for k in z.files if k.startswith("param/")}
            fields = {k: json.loads(str(z[k])) for k in z.files if not k.startswith("param/")}
    except (OSError, ValueError) as exc:
        raise TryonError(f"cannot read the model {path}: {exc}") from exc
    return state, fields


@dataclass
class EpochLoop:
    """The training schedule of one model: `epochs` passes over `train` rows in batches,
    shuffled from `seed`, each followed by a validation score."""

    epochs: int
    batch: int
    seed: int
    higher_is_better: bool
    desc: str
    score_name: str = "val"
    history: list[dict] = field(default_factory=list)
    best: float = float("nan")
    seconds: float = 0.0

    def run(self, out: Path, model: torch.nn.Module, opt: torch.optim.Optimizer, train: np.ndarray,
            step: Callable[[np.ndarray], torch.Tensor], validate: Callable[[], float],
            keep_best: Callable[[], None], progress: bool = True) -> "EpochLoop":
        """Train, resuming from `out/checkpoint.pt` when it is there. `step(rows)` returns
        the batch's loss; `validate()` the score the best model is chosen by; `keep_best()`
        saves the model (called when the score improves)."""
        sign = 1.0 if self.higher_is_better else -1.0
        start, best = 0, -float("inf")
        ckpt = out / CHECKPOINT
        if ckpt.exists():
            try:
                state = torch.load(ckpt, weights_only=True)
                model.load_state_dict(state["model"])
                opt.load_state_dict(state["opt"])
            except (RuntimeError, KeyError, ValueError, OSError) as exc:
                raise TryonError(f"{ckpt} cannot be resumed (made by another network or settings?): {exc}; "
                                 "train into a new --out") from exc
            start, best, self.history = int(state["epoch"]), sign * float(state["best"]), json.loads(state["history"])
        rng = np.random.default_rng([self.seed, 1])
        for _ in range(start):  # the shuffles of the epochs already done, so a resumed run repeats them
            rng.permutation(train)
        t0 = time.perf_counter()
        for epoch in tqdm(range(start, self.epochs), desc=self.desc, initial=start, total=self.epochs,
                          disable=not progress):
            model.train()
            order = rng.permutation(train)
            losses = []
            for i in range(0, len(order), self.batch):
                loss = step(order[i:i + self.batch])
                opt.zero_grad()
                loss.backward()
                opt.step()
                losses.append(loss.item())
            model.eval()
            score = float(validate())
            self.history.append({"epoch": epoch + 1, "train_loss": float(np.mean(losses)), self.score_name: score})
            if sign * score > best:
                best = sign * score
                keep_best()
            with atomic_write(ckpt, "wb") as fh:  # a run killed mid-write keeps the last whole checkpoint
                torch.save({"model": model.state_dict(), "opt": opt.state_dict(), "epoch": epoch + 1,
                            "best": sign * best, "history": json.dumps(self.history)}, fh)
        self.best, self.seconds = sign * best, time.perf_counter() - t0
        return self
