"""The body in a fraction of a second: a small network maps what is known of a person to
the unknowns of the prior-guided fit (`tryon.body.fit.fit_body`), and a few L-BFGS
iterations polish them (`fit_body(..., start=...)`), where the full fit takes about a
second from its warm start and more from a cold one.

The network sees the person as the fit does: gender, stature, BMI and age, and every
measurement the ANSUR II prior knows, either given or the prior's most likely value given
the rest (`prior_targets`), with a flag saying which. It is an MLP trained on full fits of
people drawn over the supported range (`tryon.body.amortised_build`, `tryon train
body-fit`) and ships as `data/amortised_fit.npz` with its card; a file made for other
controls than today's `LOCAL_CHANGES` is ignored and the full fit runs instead.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

from tryon.body.anny_model import LOCAL_CHANGES
from tryon.body.fit import GENDERS, PRIOR_TAPES, BodyFit, Measurements, fit_body, prior_targets
from tryon.body.prior import default_prior

MODEL_PATH = Path(__file__).parent / "data" / "amortised_fit.npz"
# the measurements the network sees: the prior's, and the natural waist a shopper may type
FEATURE_TAPES = (*PRIOR_TAPES, "waist")


def person_features(m: Measurements) -> np.ndarray:
    """[4 + 2 * len(FEATURE_TAPES)]: gender, stature, BMI, age, then per tape its value in
    metres (given, or the prior's; 0 for a natural waist not given) and whether given."""
    m.validate()
    aimed, _ = prior_targets(m, default_prior())
    given = m.tapes()
    bmi = m.target_bmi()
    if bmi is None:
        raise ValueError("the amortised fit needs the weight or BMI")
    x = [GENDERS[m.gender], (m.height_cm - 170.0) / 20.0, (bmi - 25.0) / 10.0, (m.age - 40.0) / 30.0]
    for tape in FEATURE_TAPES:
        value = given.get(tape, aimed.get(tape, 0.0))
        x += [value / 100.0, float(tape in given)]
    return np.array(x, np.float64)


@dataclass
class AmortisedFit:
    """The network: an MLP with SiLU activations on standardised inputs and outputs."""

    weights: list[np.ndarray]
    biases: list[np.ndarray]
    x_mean: np.ndarray
    x_sd: np.ndarray
    z_mean: np.ndarray
    z_sd: np.ndarray
    card: dict

    def predict(self, x: np.ndarray) -> np.ndarray:
        h = (np.atleast_2d(x) - self.x_mean) / self.x_sd
        for i, (w, b) in enumerate(zip(self.weights, self.biases)):
            h = h @ w + b
            if i < len(self.weights) - 1:
                h = h / (1.0 + np.exp(-h))  # SiLU
        return h * self.z_sd + self.z_mean

    def save(self, path: str | Path) -> None:
        from tryon.io.atomic import atomic_write

        arrays = {f"w{i}": w for i, w in enumerate(self.weights)} | {f"b{i}": b for i, b in enumerate(self.biases)}
        with atomic_write(path, "wb") as f:
            np.savez(f, x_mean=self.x_mean, x_sd=self.x_sd, z_mean=self.z_mean, z_sd=self.z_sd,
                     card=np.asarray(json.dumps(self.card)), **arrays)

    @classmethod
    def load(cls, path: str | Path) -> "AmortisedFit":
        with np.load(path) as a:
            n = sum(1 for k in a.files if k.startswith("w"))
            return cls([a[f"w{i}"] for i in range(n)], [a[f"b{i}"] for i in range(n)], a["x_mean"], a["x_sd"],
                       a["z_mean"], a["z_sd"], json.loads(str(a["card"])))


@lru_cache(maxsize=2)
def shipped_amortised(path: Path = MODEL_PATH) -> AmortisedFit | None:
    """The shipped network, or None when missing or made for other body controls."""
    try:
        net = AmortisedFit.load(path)
    except (OSError, ValueError, KeyError):
        return None
    return net if net.card.get("local_changes") == list(LOCAL_CHANGES) else None


def quick_fit(m: Measurements, net: AmortisedFit | None = None) -> BodyFit:
    """`fit_body(m)` from the network's start: within a few millimetres of the full fit on
    stature and every girth asked, in a fraction of its time. Without a network (or a
    weight), the full fit."""
    net = net or shipped_amortised()
    if net is None or m.target_bmi() is None:
        return fit_body(m)
    z = net.predict(person_features(m))[0]
    return fit_body(m, start=z)
