"""Judging drape predictions against the simulated drapes of a dataset's splits.

One record per (method, split): vertex error (cm, mean and 95th percentile), the share of
garment vertices inside the body (the drape report's measure), the relative edge-length
error, the potential energy (gravity from the floor + stretching + bending with the
dataset's fabric) relative to the simulated drape's, the time per drape at batch 1, and
the simulator's own time for the same samples."""

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
        from tryon.fabric import load_fabric
        from tryon.sim.model import ClothModel

        self.ts = ts
        self.edges = _edges(model.faces)
        self.bodies = [a_posed_body(shape_params(s)) for s in ts.shape]
        fabric = load_fabric(data.manifest.spec["fabric"])
        sizes = data.manifest.spec["sizes"]
        self.cloth = {}
        for g, s in {(GENDERS[int(gi)], sizes[int(si)]) for gi, si in zip(ts.gender, ts.size)}:
            self.cloth[(g, s)] = ClothModel(model.reference_garment(g, s).cloth_mesh(), fabric)
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
            cloth = self.cloth[(GENDERS[int(ts.gender[i])], self.sizes[int(ts.size[i])])]
            pot.append(potential_energy(cloth, pred[i].astype(float))["total_J"]
                       / potential_energy(cloth, ts.truth[i].astype(float))["total_J"])
        return {"err": err, "edge": 100.0 * np.abs(lp / np.maximum(lt, 1e-6) - 1.0), "pen": np.asarray(pen),
                "pot": np.asarray(pot)}

    def record(self, method: str, split: str, pred: np.ndarray, inference_ms: float, refine_s: float = 0.0) -> dict:
        m = self.measures(pred)
        return {"method": method, "split": split, "samples": len(pred),
                "mean_error_cm": float(m["err"].mean()), "p95_error_cm": float(np.percentile(m["err"], 95)),
                "interpenetration_pct": float(m["pen"].mean()), "edge_error_pct": float(m["edge"].mean()),
                "potential_ratio": float(np.median(m["pot"])), "inference_ms": inference_ms, "refine_s": refine_s,
                "simulation_s": float(self.sim_s.mean())}


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
