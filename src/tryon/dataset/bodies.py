"""Bodies for datasets: people drawn in measurement space, built as `tryon drape` builds
them.

A sample draws a gender, an age, a stature uniform in the gender's height range and a
BMI uniform in the BMI range, and fits Anny to them with the pinned fit
`tryon.body.fit.fit_body(..., prior=False)` (Anny's average shape of that stature and BMI,
as before the ANSUR II prior): the datasets in git were made so and a resumed run makes the
same bodies. `tryon drape` on such a body (`drape(request, person=...)`) gives the sample.

Sample `i` of a seed is drawn from its own generator (`numpy` seeded with `[seed, i]`), so
a dataset can grow, resume or run its samples in any order and still get the same bodies.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from tryon.body.anny_model import BodyShape, ShapeParams, body_model
from tryon.body.fit import BMI_RANGE, Measurements, fit_body
from tryon.errors import TryonError

GENDERS = ("female", "male")


@dataclass
class BodyRanges:
    """What a dataset's bodies span: genders, BMI, stature (cm) per gender, age (years)."""

    genders: tuple[str, ...] = GENDERS
    bmi: tuple[float, float] = (17.0, 45.0)
    height_cm: dict | None = None
    age_years: tuple[float, float] = (18.0, 65.0)

    def __post_init__(self) -> None:
        if self.height_cm is None:
            self.height_cm = {"female": (150.0, 185.0), "male": (160.0, 200.0)}
        self.genders = tuple(self.genders)
        self.bmi = tuple(float(b) for b in self.bmi)
        if not self.genders:
            raise TryonError("a dataset needs at least one gender")
        for g in self.genders:
            if g not in GENDERS:
                raise TryonError(f"unknown gender {g!r}; use female or male")
            lo, hi = BMI_RANGE[g]
            if self.bmi[0] < lo or self.bmi[1] > hi or self.bmi[0] >= self.bmi[1]:
                raise TryonError(f"BMI range {self.bmi[0]:g}-{self.bmi[1]:g} leaves the supported {lo:.0f}-{hi:.0f} "
                                 f"for {g} bodies")
            h = self.height_cm[g]
            if not 140.0 <= h[0] < h[1] <= 210.0:
                raise TryonError(f"height range {h} cm for {g} bodies leaves the supported 140-210 cm")
        if not 16.0 <= self.age_years[0] <= self.age_years[1] <= 90.0:
            raise TryonError(f"age range {self.age_years} leaves the supported 16-90 years")

    def to_dict(self) -> dict:
        d = asdict(self)
        d["genders"] = list(self.genders)
        d["bmi"] = list(self.bmi)
        d["age_years"] = list(self.age_years)
        d["height_cm"] = {k: list(v) for k, v in self.height_cm.items()}
        return d

    @classmethod
    def from_dict(cls, d: dict) -> "BodyRanges":
        return cls(genders=tuple(d["genders"]), bmi=tuple(d["bmi"]), age_years=tuple(d["age_years"]),
                   height_cm={k: tuple(v) for k, v in d["height_cm"].items()})


@dataclass
class BodySample:
    """One sampled person: the measurements drawn and the fitted Anny parameters."""

    index: int
    gender: str
    age_years: float
    height_cm: float
    bmi: float
    params: ShapeParams

    def shape(self) -> BodyShape:
        return body_model().rest_shape(self.params)

    def measurements(self) -> Measurements:
        return Measurements(height_cm=self.height_cm, bmi=self.bmi, gender=self.gender, age=self.age_years)


def draw_measurements(seed: int, index: int, ranges: BodyRanges) -> tuple[str, float, float, float]:
    """(gender, age, stature cm, BMI) of sample `index`: uniform in each range."""
    rng = np.random.default_rng([seed, index])
    gender = ranges.genders[int(rng.integers(len(ranges.genders)))]
    height = float(rng.uniform(*ranges.height_cm[gender]))
    bmi = float(rng.uniform(*ranges.bmi))
    age = float(rng.uniform(*ranges.age_years))
    return gender, round(age, 2), round(height, 2), round(bmi, 3)


def sample_body(seed: int, index: int, ranges: BodyRanges) -> BodySample:
    gender, age, height, bmi = draw_measurements(seed, index, ranges)
    # pinned to Anny's average shape of the stature and BMI drawn (prior=False): the datasets
    # in git were made so, and a resumed run must make the same bodies
    fit = fit_body(Measurements(height_cm=height, bmi=bmi, gender=gender, age=age), prior=False)
    return BodySample(index, gender, age, height, bmi, fit.params)
