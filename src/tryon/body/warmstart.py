"""A warm start for the prior-guided body fit: Anny's unknowns predicted from stature, BMI
and age, so L-BFGS starts near the answer and needs a fraction of its iterations.

Per gender, each unknown of `fit._Problem` (phenotype logits, local-change atanh values) is
a quadratic polynomial of t = (stature - 170 cm) / 20, b = (BMI - 25) / 10 and
a = (age - 40) / 30, fitted by ridge least squares to full fits of people drawn uniformly
over the supported range (`warmstart_build.build`, `tryon body-warmstart --rebuild`). The coefficients
ship as `data/fit_warmstart.json` with the settings that made them; a file made for other
controls than today's `LOCAL_CHANGES` is ignored (the fit then starts cold, as before).
"""

from __future__ import annotations

import json
from functools import lru_cache
from pathlib import Path

import numpy as np
import torch

from tryon.body.anny_model import DTYPE, LOCAL_CHANGES

WARMSTART_JSON = Path(__file__).parent / "data" / "fit_warmstart.json"
RIDGE = 1e-3
Z_LIMIT = 6.0  # logits and atanh values beyond this are saturated: no use starting further out


def features(height_cm: float, bmi: float, age: float) -> np.ndarray:
    t, b, a = (height_cm - 170.0) / 20.0, (bmi - 25.0) / 10.0, (age - 40.0) / 30.0
    return np.array([1.0, t, b, a, t * t, b * b, a * a, t * b, t * a, b * a])


@lru_cache(maxsize=2)
def load_warmstart(path: Path = WARMSTART_JSON) -> dict | None:
    """The shipped coefficients, or None when missing or made for other controls."""
    try:
        doc = json.loads(Path(path).read_text())
    except (OSError, ValueError):
        return None
    if doc.get("local_changes") != list(LOCAL_CHANGES):
        return None
    return {g: np.asarray(d["coef"]) for g, d in doc["genders"].items()}


def initial_unknowns(gender: str, height_cm: float, bmi: float, age: float, size: int) -> torch.Tensor | None:
    """The predicted unknowns for this person, or None without a usable warm start."""
    coef = (load_warmstart() or {}).get(gender)
    if coef is None or coef.shape[0] != size:
        return None
    z = coef @ features(height_cm, bmi, age)
    return torch.from_numpy(np.clip(z, -Z_LIMIT, Z_LIMIT)).to(DTYPE)
