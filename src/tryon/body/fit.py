"""Anny shape parameters from a person's measurements.

Given stature, weight (or BMI), gender and age, and optionally chest / waist / hip girths
(defined in `tryon.body.measure`), `fit_body` solves for Anny's continuous phenotypes
(weight, muscle, height, proportions) and the local shape controls of
`anny_model.LOCAL_CHANGES` by L-BFGS on the differentiable measurements, with a small
pull of muscle, proportions and local changes towards neutral so that unasked-for
features stay average. The result reports every measurement asked and achieved.

Supported range (see `tryon body-range`, docs/BODY.md): adults 16-90 years, stature
140-210 cm and BMI `BMI_RANGE`; beyond it Anny's mesh distorts, so the fit refuses.
"""

from __future__ import annotations

import math
import time
from dataclasses import asdict, dataclass, field

import torch

from tryon.body.anny_model import DTYPE, LOCAL_CHANGES, BodyShape, ShapeParams, body_model, years_to_anny_age
from tryon.body.measure import GIRTH_BANDS, bmi, girth, measurements, stature
from tryon.errors import TryonError

# per gender: where the fitted mesh still looks like a person (docs/BODY.md, `tryon body-range --render`)
BMI_RANGE = {"female": (15.0, 45.0), "male": (17.0, 45.0)}
HEIGHT_RANGE_CM = (140.0, 210.0)
AGE_RANGE = (16.0, 90.0)
GIRTH_RANGE_CM = {"chest": (65.0, 160.0), "waist": (50.0, 160.0), "hip": (70.0, 170.0)}
GENDERS = {"male": 0.0, "female": 1.0}
# residual scales: 0.5 cm of stature, 0.1 BMI, 0.5 cm of girth weigh as much as moving
# one neutral-pulled control by half its range
SCALE = {"height": 0.005, "bmi": 0.1, "girth": 0.005}
NEUTRAL_PULL = 0.5


class BodyFitError(TryonError):
    """Measurements that Anny cannot represent, or an inconsistent request."""


@dataclass
class Measurements:
    """What a user knows about a person. Give `weight_kg` or `bmi` (not both)."""

    height_cm: float
    gender: str = "female"
    weight_kg: float | None = None
    bmi: float | None = None
    age: float = 30.0
    chest_cm: float | None = None
    waist_cm: float | None = None
    hip_cm: float | None = None

    def target_bmi(self) -> float | None:
        if self.bmi is not None:
            return float(self.bmi)
        if self.weight_kg is None:
            return None
        return float(self.weight_kg) / (self.height_cm / 100.0) ** 2

    def girths(self) -> dict[str, float]:
        return {k: getattr(self, f"{k}_cm") for k in GIRTH_BANDS if getattr(self, f"{k}_cm") is not None}

    def validate(self) -> None:
        if self.gender not in GENDERS:
            raise BodyFitError(f"gender must be one of {sorted(GENDERS)}, got {self.gender!r}")
        for name in ("height_cm", "weight_kg", "bmi", "age", "chest_cm", "waist_cm", "hip_cm"):
            value = getattr(self, name)
            if value is not None and not (isinstance(value, (int, float)) and math.isfinite(value)):
                raise BodyFitError(f"{name} must be a finite number, got {value!r}")
        if self.weight_kg is not None and self.bmi is not None:
            raise BodyFitError("give one of weight (kg) and BMI, not both")
        if self.weight_kg is None and self.bmi is None and len(self.girths()) < 2:
            raise BodyFitError("give the weight (kg) or BMI, or at least two of the chest, waist and hip girths")
        _check_range("height", self.height_cm, HEIGHT_RANGE_CM, "cm")
        _check_range("age", self.age, AGE_RANGE, "years")
        if self.weight_kg is not None and self.weight_kg <= 0:
            raise BodyFitError(f"weight must be positive, got {self.weight_kg} kg")
        b = self.target_bmi()
        lo, hi = BMI_RANGE[self.gender]
        if b is not None and not lo <= b <= hi:
            h = self.height_cm / 100.0
            raise BodyFitError(
                f"BMI {b:.1f} is outside the supported range {lo:.0f}-{hi:.0f} for a {self.gender} body "
                f"(at {self.height_cm:.0f} cm: {lo * h * h:.0f}-{hi * h * h:.0f} kg); "
                f"beyond it the Anny body mesh distorts"
            )
        for name, value in self.girths().items():
            _check_range(f"{name} girth", value, GIRTH_RANGE_CM[name], "cm")


def _check_range(name: str, value: float, bounds: tuple[float, float], unit: str) -> None:
    if not bounds[0] <= value <= bounds[1]:
        raise BodyFitError(f"{name} {value:g} {unit} is outside the supported range {bounds[0]:g}-{bounds[1]:g} {unit}")


@dataclass
class BodyFit:
    """The fitted body, its parameters and the measurements asked and achieved."""

    shape: BodyShape
    params: ShapeParams
    asked: dict[str, float]
    achieved: dict[str, float]
    iterations: int
    wall_s: float
    distortion: float = 0.0
    notes: list[str] = field(default_factory=list)

    def report(self) -> dict:
        return {
            "asked": self.asked,
            "achieved": self.achieved,
            "error": {k: self.achieved[k] - v for k, v in self.asked.items() if k in self.achieved},
            "params": self.params.to_dict(),
            "iterations": self.iterations,
            "wall_s": self.wall_s,
            "mesh_distortion": self.distortion,
        }


def _logit(p: float) -> float:
    p = min(max(p, 1e-4), 1 - 1e-4)
    return math.log(p / (1 - p))


class _Problem:
    """Unknowns: logits of (weight, muscle, height, proportions) and atanh of local changes."""

    def __init__(self, m: Measurements):
        self.m = m
        self.model = body_model()
        self.gender = GENDERS[m.gender]
        self.age = years_to_anny_age(m.age)
        self.target = {"height": m.height_cm / 100.0, "bmi": m.target_bmi()}
        self.girths = {k: v / 100.0 for k, v in m.girths().items()}

    def shape(self, z: torch.Tensor) -> BodyShape:
        w, mu, h, pr = torch.sigmoid(z[:4])
        ph = torch.stack([z.new_tensor(self.gender), z.new_tensor(self.age), mu, w, h, pr])[None]
        lc = torch.tanh(z[4:])[None]
        return self.model.rest_shape(ShapeParams(gender=self.gender, age=self.age), phenotypes=ph, local=lc)

    def loss(self, z: torch.Tensor) -> torch.Tensor:
        s = self.shape(z)
        v = s.vertices
        r = [(stature(v) - self.target["height"]) / SCALE["height"]]
        if self.target["bmi"] is not None:
            r.append((bmi(v, s.faces) - self.target["bmi"]) / SCALE["bmi"])
        for name, value in self.girths.items():
            r.append((girth(s, name, v)[0] - value) / SCALE["girth"])
        _, mu, _, pr = torch.sigmoid(z[:4])
        pull = torch.cat([(torch.stack([mu, pr]) - 0.5) / 0.5, torch.tanh(z[4:])]) / NEUTRAL_PULL
        return sum(x * x for x in r) + 0.25 * (pull * pull).sum()

    def initial(self) -> torch.Tensor:
        """Stature and BMI are nearly monotonic in the height and weight phenotypes: start
        from a linear interpolation of two probes each."""
        z = torch.zeros(4 + len(LOCAL_CHANGES), dtype=DTYPE)
        with torch.no_grad():
            probes = []
            for p in (0.15, 0.85):
                z[0] = z[2] = _logit(p)
                s = self.shape(z)
                probes.append((float(stature(s.vertices)), float(bmi(s.vertices, s.faces))))
        (h0, b0), (h1, b1) = probes
        z[2] = _logit(0.15 + 0.7 * (self.target["height"] - h0) / max(h1 - h0, 1e-6))
        if self.target["bmi"] is not None:
            z[0] = _logit(0.15 + 0.7 * (self.target["bmi"] - b0) / max(b1 - b0, 1e-6))
        return z


def fit_body(m: Measurements, max_iter: int = 60, progress: bool = False) -> BodyFit:
    """Solve Anny's shape for `m`; raises `BodyFitError` outside the supported range."""
    m.validate()
    t0 = time.perf_counter()
    prob = _Problem(m)
    z = prob.initial().requires_grad_(True)
    opt = torch.optim.LBFGS([z], lr=1.0, max_iter=max_iter, line_search_fn="strong_wolfe", tolerance_grad=1e-6, tolerance_change=1e-9)
    evals = [0]

    def closure():
        opt.zero_grad()
        loss = prob.loss(z)
        loss.backward()
        evals[0] += 1
        return loss

    opt.step(closure)
    with torch.no_grad():
        shape = prob.shape(z.detach()).detached()
    w, mu, h, pr = (float(x) for x in torch.sigmoid(z.detach()[:4]))
    lc = torch.tanh(z.detach()[4:]).numpy()
    params = ShapeParams(gender=prob.gender, age=prob.age, muscle=mu, weight=w, height=h, proportions=pr,
                         local={k: float(x) for k, x in zip(LOCAL_CHANGES, lc)})
    shape.params = params
    achieved = measurements(shape)
    asked = {"height_cm": m.height_cm}
    if m.target_bmi() is not None:
        asked["bmi"] = m.target_bmi()
    if m.weight_kg is not None:
        asked["weight_kg"] = m.weight_kg
    asked.update({f"{k}_cm": v for k, v in m.girths().items()})
    fit = BodyFit(shape, params, asked, achieved, evals[0], time.perf_counter() - t0, distortion=mesh_distortion(shape))
    for key, tol in (("height_cm", 1.0), ("bmi", 0.5), ("chest_cm", 2.0), ("waist_cm", 2.0), ("hip_cm", 2.0)):
        if key in asked and abs(achieved[key] - asked[key]) > tol:
            fit.notes.append(f"{key}: asked {asked[key]:.1f}, achieved {achieved[key]:.1f} (the measurements may be inconsistent for Anny)")
    return fit


def mesh_distortion(shape: BodyShape) -> float:
    """Largest relative change of an edge length against Anny's average body of the same
    gender and age scaled to the same stature: |log(l / l_ref)|, max over edges. Neutral
    bodies score 0; it grows where local changes or extreme phenotypes stretch the mesh."""
    model = body_model()
    ref = model.rest_shape(ShapeParams(gender=shape.params.gender, age=shape.params.age)).vertices.detach()
    v = shape.vertices.detach()
    ref = ref * (stature(v) / stature(ref))
    f = torch.from_numpy(shape.faces)
    e = torch.cat([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    length = torch.linalg.norm(v[e[:, 0]] - v[e[:, 1]], dim=1)
    length_ref = torch.linalg.norm(ref[e[:, 0]] - ref[e[:, 1]], dim=1)
    return float(torch.log(length / length_ref).abs().max())


def measurement_dict(m: Measurements) -> dict:
    return {k: v for k, v in asdict(m).items() if v is not None}
