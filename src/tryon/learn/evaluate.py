"""Judging drape predictions against the simulated drapes of a dataset's splits.

One record per (method, split): vertex error (cm, mean and 95th percentile), the share of
garment vertices inside the body (the drape report's measure), the relative edge-length
error, the potential energy (gravity from the floor + stretching + bending in the drape's
own fabric) relative to the simulated drape's, the time per drape at batch 1, and the
simulator's own time for the same samples. On data whose fabric is drawn per drape, the
same measures per fabric (`records_by_fabric`)."""

from __future__ import annotations

import time
from typing import Callable

import numpy as np

from tryon.dataset.drapes import shape_params
from tryon.dataset.loading import DrapeDataset
from tryon.learn.data import GENDERS, TrainingSet
from tryon.learn.features import a_posed_body
from tryon.learn.model import DrapeModel


def _edges(faces: np.ndarray) -> np.ndarray:
    e = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    return np.unique(np.sort(e, 1), axis=0)


class Judge:
    """Per-sample measures of predicted garments on one evaluation set."""

    def __init__(self, data: DrapeDataset, ts: TrainingSet, model: DrapeModel):
        from tryon.dataset.drapes import fabric_group, fabric_named
        from tryon.sim.model import ClothModel

        self.ts = ts
        self.garment = model.garment
        self.edges = _edges(model.faces)
        self.bodies = [a_posed_body(shape_params(s)) for s in ts.shape]
        made = {name: fabric_named(name) for name in set(ts.fabric_name.tolist())}
        self.fabrics = [made[name] for name in ts.fabric_name]   # each drape's own
        self.fabric_labels = [fabric_group(name) for name in ts.fabric_name]
        sizes = data.manifest.spec["sizes"]
        cloth: dict = {}
        self.cloth = []
        for gi, si, fabric in zip(ts.gender, ts.size, self.fabrics):
            key = (GENDERS[int(gi)], sizes[int(si)], fabric.name)
            if key not in cloth:
                cloth[key] = ClothModel(model.reference_garment(*key[:2]).cloth_mesh(), fabric)
            self.cloth.append(cloth[key])
        self.sim_s = data.arrays["wall_s"][ts.rows].astype(float)
        self.sizes = sizes

    def measures(self, pred: np.ndarray) -> dict[str, np.ndarray]:
        from tryon.drape.fit_metrics import penetration, potential_energy

        ts = self.ts
        err = 100.0 * np.linalg.norm(pred - ts.truth, axis=-1)               # [S,N]
        lp = np.linalg.norm(pred[:, self.edges[:, 0]] - pred[:, self.edges[:, 1]], axis=-1)
        lt = np.linalg.norm(ts.truth[:, self.edges[:, 0]] - ts.truth[:, self.edges[:, 1]], axis=-1)
        pen, pot = [], []
        for i, body in enumerate(self.bodies):
            pen.append(penetration(pred[i].astype(float), body.vertices, body.faces)["penetration_pct"])
            cloth = self.cloth[i]
            pot.append(potential_energy(cloth, pred[i].astype(float))["total_J"]
                       / potential_energy(cloth, ts.truth[i].astype(float))["total_J"])
        return {"err": err, "edge": 100.0 * np.abs(lp / np.maximum(lt, 1e-6) - 1.0), "pen": np.asarray(pen),
                "pot": np.asarray(pot)}

    def record(self, method: str, split: str, pred: np.ndarray, inference_ms: float, refine_s: float = 0.0,
               measures: dict | None = None) -> dict:
        """The record of every drape (`measures`: those of `pred`, when already taken)."""
        m = measures if measures is not None else self.measures(pred)
        return self._summary(method, split, m, np.ones(len(pred), bool), inference_ms, refine_s, "all")

    def records_by_fabric(self, method: str, split: str, pred: np.ndarray, inference_ms: float,
                          refine_s: np.ndarray | None = None, measures: dict | None = None) -> list[dict]:
        """One record per fabric of the drapes (a blend of two measured fabrics: `blended`);
        `refine_s` per drape."""
        m = measures if measures is not None else self.measures(pred)
        labels = np.asarray(self.fabric_labels)
        out = []
        for label in sorted(set(self.fabric_labels)):
            keep = labels == label
            secs = float(np.mean(refine_s[keep])) if refine_s is not None else 0.0
            out.append(self._summary(method, split, m, keep, inference_ms, secs, label))
        return out

    def _summary(self, method: str, split: str, m: dict, keep: np.ndarray, inference_ms: float, refine_s: float,
                 fabric: str) -> dict:
        return {"method": method, "split": split, "garment": self.garment, "fabric": fabric, "samples": int(keep.sum()),
                "mean_error_cm": float(m["err"][keep].mean()), "p95_error_cm": float(np.percentile(m["err"][keep], 95)),
                "interpenetration_pct": float(m["pen"][keep].mean()), "edge_error_pct": float(m["edge"][keep].mean()),
                "potential_ratio": float(np.median(m["pot"][keep])), "inference_ms": inference_ms,
                "refine_s": refine_s, "simulation_s": float(self.sim_s[keep].mean())}


def timed(predict: Callable[[TrainingSet], np.ndarray], ts: TrainingSet, one: Callable[[int], object] | None = None,
          repeats: int = 20) -> tuple[np.ndarray, float]:
    """Predictions for the whole set, and the median milliseconds of one prediction at batch 1."""
    pred = predict(ts)
    times = []
    for i in range(min(repeats, len(ts.rows))):
        t = time.perf_counter()
        (one or (lambda k: predict(ts.subset(np.array([k])))))(i)
        times.append(1000.0 * (time.perf_counter() - t))
    return pred, float(np.median(times)) if times else float("nan")
