"""Rebuilding the body fit's warm start (`tryon body-warmstart --rebuild`): cold fits of
people drawn uniformly over the supported range, one process per gender, and the ridge
regression of their unknowns (`tryon.body.warmstart` reads the result)."""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

from tryon.body.anny_model import LOCAL_CHANGES
from tryon.body.fit import AGE_RANGE, BMI_RANGE, HEIGHT_RANGE_CM, Measurements, fit_body
from tryon.body.warmstart import RIDGE, WARMSTART_JSON, Z_LIMIT, features, load_warmstart


def draw_people(n: int, seed: int, gender: str) -> list[tuple[float, float, float]]:
    """(stature cm, BMI, age) drawn uniformly over the supported range of `gender`."""
    rng = np.random.default_rng([seed, 0 if gender == "male" else 1])
    lo_h, hi_h = HEIGHT_RANGE_CM[0] + 5.0, HEIGHT_RANGE_CM[1] - 5.0
    return [(float(rng.uniform(lo_h, hi_h)), float(rng.uniform(*BMI_RANGE[gender])),
             float(rng.uniform(AGE_RANGE[0] + 2.0, 80.0))) for _ in range(n)]


def solve_samples(gender: str, people: list[tuple[float, float, float]], progress: bool = False) -> np.ndarray:
    """The fitted unknowns [N, Z] of each person (cold starts: the thing being learned)."""
    from tqdm import tqdm

    rows = []
    for h, b, a in tqdm(people, desc=f"warm start {gender}", disable=not progress, unit="fit"):
        fit = fit_body(Measurements(height_cm=h, bmi=b, gender=gender, age=a), warm_start=False)
        rows.append(fit.unknowns)
    return np.stack(rows)


def regress(people: list[tuple[float, float, float]], z: np.ndarray) -> np.ndarray:
    x = np.stack([features(*p) for p in people])
    z = np.clip(z, -Z_LIMIT, Z_LIMIT)
    return np.linalg.solve(x.T @ x + RIDGE * np.eye(x.shape[1]), x.T @ z)


def _gender_rows(args: tuple[str, int, int, bool]) -> tuple[str, list, np.ndarray]:
    import torch as _torch

    gender, n, seed, progress = args
    _torch.set_num_threads(1)
    people = draw_people(n, seed, gender)
    return gender, people, solve_samples(gender, people, progress)


def build(n: int = 160, seed: int = 0, path: Path = WARMSTART_JSON, genders=("male", "female"),
          progress: bool = True, processes: int = 2) -> dict:
    """Fit `n` people per gender cold (one process per gender) and write the regression of
    their unknowns. About 8 minutes for 160 per gender on two cores."""
    from concurrent.futures import ProcessPoolExecutor

    t0 = time.perf_counter()
    doc = {"local_changes": list(LOCAL_CHANGES), "n": n, "seed": seed, "ridge": RIDGE, "genders": {}}
    jobs = [(g, n, seed, progress) for g in genders]
    if processes > 1:
        with ProcessPoolExecutor(max_workers=min(processes, len(jobs))) as pool:
            results = list(pool.map(_gender_rows, jobs))
    else:
        results = [_gender_rows(j) for j in jobs]
    for gender, people, z in results:
        coef = regress(people, z)
        pred = np.stack([features(*p) for p in people]) @ coef
        doc["genders"][gender] = {"coef": coef.T.round(6).tolist(),
                                  "train_rms": float(np.sqrt(((pred - np.clip(z, -Z_LIMIT, Z_LIMIT)) ** 2).mean()))}
    doc["build_s"] = time.perf_counter() - t0
    tmp = Path(path).with_suffix(".tmp")
    tmp.write_text(json.dumps(doc) + "\n")
    tmp.replace(path)
    load_warmstart.cache_clear()
    return doc
