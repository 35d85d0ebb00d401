"""A population prior of body measurements from real people (ANSUR II).

ANSUR II (Gordon et al. 2014, NATICK/TR-15/007; public domain) measured 4,082 men and
1,986 women. Per sex, the log of each measurement in `PRIOR_MEASUREMENTS` (weight
included) is modelled as a Gaussian whose mean is linear in log stature, age and age
squared, with a full residual covariance:

    log y = B [1, log h, a, a^2] + e,   e ~ N(0, S),   a = (age - 35) / 20

Conditioning that Gaussian on whatever a person gives (weight, any girth or length) yields
the most likely value and the spread of everything else: given the weight only, it is the
log-linear regression of each measurement on stature, weight and age; given a girth too,
the others move with it as they do in real people. The model is a few KB of JSON
(`data/ansur2_prior.json`, card `data/ansur2_prior.md`), rebuilt by `tryon body-prior --rebuild`.

Ages are clamped to the survey's 17-58 years when the prior is evaluated: the quadratic
in age is not trusted outside the data.
"""

from __future__ import annotations

import csv
import gzip
import json
import math
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

from tryon.errors import TryonError

DATA_DIR = Path(__file__).parent / "data"
ANSUR_CSV = DATA_DIR / "ansur2" / "ansur2_subset.csv.gz"
PRIOR_JSON = DATA_DIR / "ansur2_prior.json"
AGE_RANGE = (17.0, 58.0)

# tryon's name -> the ANSUR II column (mm, weight in tenths of a kg); see docs/BODY.md
PRIOR_MEASUREMENTS = {
    "weight_kg": "weightkg",
    "chest_cm": "chestcircumference",
    "waist_navel_cm": "waistcircumference",
    "hip_cm": "buttockcircumference",
    "neck_cm": "neckcircumferencebase",
    "thigh_cm": "thighcircumference",
    "crotch_height_cm": "crotchheight",
    "waist_height_cm": "waistheightomphalion",
    "shoulder_width_cm": "biacromialbreadth",
    "arm_length_cm": "acromion_stylion",  # acromionradialelength + radialestylionlength
    "wrist_cm": "wristcircumference",
}
SEXES = ("male", "female")


@dataclass
class Person:
    """One ANSUR II participant, in tryon's units (cm, kg, years)."""

    subject: int
    gender: str
    age: float
    height_cm: float
    values: dict[str, float]

    @property
    def bmi(self) -> float:
        return self.values["weight_kg"] / (self.height_cm / 100.0) ** 2


def load_ansur(path: Path = ANSUR_CSV) -> list[Person]:
    """Every participant of the packaged ANSUR II subset (the columns tryon uses)."""
    people = []
    with gzip.open(path, "rt", newline="") as f:
        for row in csv.DictReader(f):
            mm = {k: float(v) for k, v in row.items() if k not in ("Gender", "subjectid")}
            mm["acromion_stylion"] = mm["acromionradialelength"] + mm["radialestylionlength"]
            values = {name: mm[col] / 10.0 for name, col in PRIOR_MEASUREMENTS.items()}
            people.append(Person(int(row["subjectid"]), row["Gender"].lower(), mm["Age"], mm["stature"] / 10.0, values))
    return people


def held_out(people: list[Person], every: int = 5) -> tuple[list[Person], list[Person]]:
    """The fixed split: per sex, people ordered by BMI (then subject id), every `every`-th
    held out (20 %), so the held-out people span each sex's BMI range as the rest do."""
    train, test = [], []
    for sex in SEXES:
        group = sorted((p for p in people if p.gender == sex), key=lambda p: (p.bmi, p.subject))
        for i, p in enumerate(group):
            (test if i % every == every - 1 else train).append(p)
    return train, test


def _features(height_cm: float, age: float) -> np.ndarray:
    a = (min(max(age, AGE_RANGE[0]), AGE_RANGE[1]) - 35.0) / 20.0
    return np.array([1.0, math.log(height_cm), a, a * a])


def fit_prior(people: list[Person]) -> dict:
    """Least squares of log measurements on the features, per sex, and the residual
    covariance: the JSON document `AnthropometricPrior` reads."""
    names = list(PRIOR_MEASUREMENTS)
    out = {"model": "log y = B [1, log height_cm, a, a^2] + N(0, S), a = (clamp(age, 17, 58) - 35) / 20",
           "measurements": names, "sexes": {}}
    for sex in SEXES:
        group = [p for p in people if p.gender == sex]
        x = np.stack([_features(p.height_cm, p.age) for p in group])
        y = np.log(np.array([[p.values[n] for n in names] for p in group]))
        coef, *_ = np.linalg.lstsq(x, y, rcond=None)
        resid = y - x @ coef
        cov = resid.T @ resid / (len(group) - x.shape[1])
        out["sexes"][sex] = {"n": len(group), "coef": coef.T.round(8).tolist(), "cov": cov.round(10).tolist()}
    return out


@dataclass
class Prediction:
    """Most likely value (the conditional median) and 1-sigma spread of each measurement."""

    mean: dict[str, float]
    sd: dict[str, float]


class AnthropometricPrior:
    """The conditional Gaussian of `PRIOR_MEASUREMENTS` given stature, sex and age."""

    def __init__(self, doc: dict):
        self.names: list[str] = list(doc["measurements"])
        self.coef = {s: np.asarray(d["coef"]) for s, d in doc["sexes"].items()}
        self.cov = {s: np.asarray(d["cov"]) for s, d in doc["sexes"].items()}

    @classmethod
    def load(cls, path: Path = PRIOR_JSON) -> "AnthropometricPrior":
        try:
            return cls(json.loads(Path(path).read_text()))
        except (OSError, ValueError, KeyError) as exc:
            raise TryonError(f"cannot read the anthropometric prior {path}: {exc}") from exc

    def predict(self, gender: str, height_cm: float, age: float, known: dict[str, float] | None = None) -> Prediction:
        """Every prior measurement given stature, sex, age and the `known` ones (which are
        returned as given, with sd 0)."""
        if gender not in self.coef:
            raise TryonError(f"the prior knows {sorted(self.coef)} bodies, not {gender!r}")
        known = {k: float(v) for k, v in (known or {}).items() if k in self.names and v is not None}
        for k, v in known.items():
            if not v > 0:
                raise TryonError(f"{k} must be positive, got {v}")
        mu = self.coef[gender] @ _features(height_cm, age)
        cov = self.cov[gender]
        obs = [self.names.index(k) for k in known]
        free = [i for i in range(len(self.names)) if i not in obs]
        mean, var = mu.copy(), np.diag(cov).copy()
        if obs:
            y = np.log([known[self.names[i]] for i in obs])
            gain = cov[np.ix_(free, obs)] @ np.linalg.inv(cov[np.ix_(obs, obs)])
            mean[free] = mu[free] + gain @ (y - mu[obs])
            var[free] = np.diag(cov[np.ix_(free, free)] - gain @ cov[np.ix_(obs, free)])
            mean[obs], var[obs] = y, 0.0
        value = np.exp(mean)
        return Prediction({n: float(value[i]) for i, n in enumerate(self.names)},
                          {n: float(value[i] * math.sqrt(max(var[i], 0.0))) for i, n in enumerate(self.names)})

    def sample(self, gender: str, height_cm: float, age: float, known: dict[str, float], rng: np.random.Generator,
               limit_sd: float = 2.5) -> dict[str, float]:
        """One person drawn from the conditional Gaussian given stature, sex, age and the
        `known` measurements (returned as given), every measurement within `limit_sd` of
        its conditional spread (draws beyond are drawn again)."""
        if gender not in self.coef:
            raise TryonError(f"the prior knows {sorted(self.coef)} bodies, not {gender!r}")
        mu, cov = self.coef[gender] @ _features(height_cm, age), self.cov[gender]
        obs = [self.names.index(k) for k in known if k in self.names]
        free = [i for i in range(len(self.names)) if i not in obs]
        mean, c = mu[free], cov[np.ix_(free, free)]
        if obs:
            gain = cov[np.ix_(free, obs)] @ np.linalg.inv(cov[np.ix_(obs, obs)])
            mean = mean + gain @ (np.log([known[self.names[i]] for i in obs]) - mu[obs])
            c = c - gain @ cov[np.ix_(obs, free)]
        chol, sd = np.linalg.cholesky(c + 1e-12 * np.eye(len(free))), np.sqrt(np.diag(c))
        for _ in range(1000):  # rejection: every measurement within limit_sd of its own spread
            draw = mean + chol @ rng.standard_normal(len(free))
            if (np.abs(draw - mean) <= limit_sd * sd).all():
                break
        draw = np.clip(draw, mean - limit_sd * sd, mean + limit_sd * sd)
        out = {self.names[i]: float(np.exp(v)) for i, v in zip(free, draw)}
        out.update({self.names[i]: float(known[self.names[i]]) for i in obs})
        return out


@lru_cache(maxsize=1)
def default_prior() -> AnthropometricPrior:
    """The shipped prior, fitted on the training split of ANSUR II (`held_out`)."""
    return AnthropometricPrior.load()


def rebuild(path: Path = PRIOR_JSON) -> dict:
    """Fit the prior on the training split and write it (with its card's numbers)."""
    people = load_ansur()
    train, test = held_out(people)
    doc = fit_prior(train)
    doc["data"] = "ANSUR II public release (Gordon et al. 2014, NATICK/TR-15/007), public domain"
    doc["split"] = {"rule": "per sex, by BMI then subject id, every 5th person held out",
                    "train": len(train), "test": len(test)}
    prior = AnthropometricPrior(doc)
    doc["test_mean_rel_pct_given_weight"] = regression_errors(prior, test)
    tmp = Path(path).with_suffix(".tmp")
    tmp.write_text(json.dumps(doc, indent=1) + "\n")
    tmp.replace(path)
    return doc


def regression_errors(prior: AnthropometricPrior, people: list[Person]) -> dict[str, float]:
    """Mean relative error (%) of each measurement predicted from stature, weight and age."""
    errs: dict[str, list[float]] = {n: [] for n in prior.names if n != "weight_kg"}
    for p in people:
        pred = prior.predict(p.gender, p.height_cm, p.age, {"weight_kg": p.values["weight_kg"]})
        for n in errs:
            errs[n].append(abs(pred.mean[n] - p.values[n]) / p.values[n])
    return {n: round(100.0 * float(np.mean(e)), 3) for n, e in errs.items()}
