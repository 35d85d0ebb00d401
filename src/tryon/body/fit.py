"""Anny shape parameters from a person's measurements.

Given stature, weight (or BMI), gender and age, and optionally any of the tape
measurements of `tryon.body.tape` (chest, natural waist, waist at the navel, hip, neck,
thigh, crotch height, shoulder width, arm length, navel height), `fit_body` solves for
Anny's continuous phenotypes (weight, muscle, height, proportions) and the local shape
controls of `anny_model.LOCAL_CHANGES` by L-BFGS on the differentiable measurements, with
a small pull of muscle, proportions and local changes towards neutral.

What is not given comes from real people: the ANSUR II prior (`tryon.body.prior`) gives
the most likely value of every other measurement for this stature, weight, sex and age,
conditioned on the ones given, and the fit aims at those too (more loosely than at the
asked ones). `prior=False` gives the body Anny's own average shape makes of the asked
numbers instead (the bodies of the pose and drape datasets and of the size charts' fit
models, pinned to it). The result reports every measurement asked, aimed at and achieved.

Supported range (see `tryon body-range`, docs/BODY.md): adults 16-90 years, stature
140-210 cm and BMI `BMI_RANGE`; beyond it Anny's mesh distorts, so the fit refuses.
"""

from __future__ import annotations

import math
import time
from dataclasses import asdict, dataclass, field

import numpy as np
import torch

from tryon.body.anny_model import DTYPE, LEGACY_LOCAL_CHANGES, LOCAL_CHANGES, BodyShape, ShapeParams, body_model, years_to_anny_age
from tryon.body.measure import GIRTH_BANDS, bmi, girth, measurements, stature
from tryon.body.prior import AnthropometricPrior, default_prior
from tryon.body.tape import Landmarks, find_landmarks, tape, tape_measurements
from tryon.errors import TryonError

# per gender: where the fitted mesh still looks like a person (docs/BODY.md, `tryon body-range --render`)
BMI_RANGE = {"female": (15.0, 45.0), "male": (17.0, 45.0)}
HEIGHT_RANGE_CM = (140.0, 210.0)
AGE_RANGE = (16.0, 90.0)
GIRTH_RANGE_CM = {"chest": (65.0, 160.0), "waist": (50.0, 160.0), "hip": (70.0, 170.0)}
# the other measurements a person may give (cm): tape name -> supported range
TAPE_RANGE_CM = {"waist_navel": (50.0, 170.0), "neck": (25.0, 65.0), "thigh": (35.0, 100.0),
                 "crotch_height": (55.0, 105.0), "shoulder_width": (28.0, 55.0), "arm_length": (40.0, 80.0),
                 "waist_height": (75.0, 135.0), "wrist": (11.0, 25.0)}
GENDERS = {"male": 0.0, "female": 1.0}
# residual scales: 0.5 cm of stature, 0.1 BMI, 0.5 cm of girth weigh as much as moving
# one neutral-pulled control by half its range
SCALE = {"height": 0.005, "bmi": 0.1, "girth": 0.005}
# a measurement the prior predicts (not asked) pulls with a 1 cm scale: the asked ones win;
# stature, which every length scales with, is held to 2 mm then
PRIOR_SCALE = 0.01
PRIOR_HEIGHT_SCALE = 0.002
# The volume a BMI asks for has to go somewhere Anny's controls can put it. A measurement
# people differ little in (neck, wrist: a prior sd of 0.5-1.5 cm) is held in proportion to
# its sd below PRIOR_SD_REF (cm), so the volume does not settle where real people vary
# least; hip and thigh, between which it went back and forth (a woman's thigh +1.5 cm
# and hip -1.7 cm against the prior), are held to 0.5 cm each.
PRIOR_SD_REF = 4.5
PRIOR_SCALE_OF = {"thigh": 0.005, "hip": 0.005}
# In the prior-guided fit the neck's controls may go to twice their targets and the fat
# controls of the torso and thighs to 1.5 times (MakeHuman targets are linear offsets):
# Anny's heaviest bodies (BMI 40+) otherwise ran out of places to carry their weight but
# the neck (+6 cm). Not the arms: fuller upper arms overstretched T-shirt sleeves that
# had fitted (a 168 cm, 85 kg woman's L and XL, 38-40 % of their area)
LOCAL_RANGE = {"measure-neck-circ-incr": 2.0, "neck-scale-depth-incr": 2.0, "neck-scale-horiz-incr": 2.0,
               "l-upperleg-fat-incr": 1.5, "r-upperleg-fat-incr": 1.5, "measure-thigh-circ-incr": 1.5,
               "measure-hips-circ-incr": 1.5, "buttocks-volume-incr": 1.5, "stomach-pregnant-incr": 1.5}
NEUTRAL_PULL = 0.5
# the local changes the fit used before the anthropometric prior: the pinned (prior=False) fit
LEGACY_LOCAL = LEGACY_LOCAL_CHANGES
# left and right controls move together in the prior-guided fit (limbs are measured on the
# left; free sides would let one thigh or arm take the volume the BMI asks)
SYMMETRIC = (("l-upperleg-fat-incr", "r-upperleg-fat-incr"), ("l-upperarm-fat-incr", "r-upperarm-fat-incr"),
             ("l-lowerarm-fat-incr", "r-lowerarm-fat-incr"), ("l-hand-scale-incr", "r-hand-scale-incr"))
# Anny's own ratio of these to the survey's girths holds where the survey is silent
SHAPE_RATIOS = {"waist": "waist_navel", "underbust": "chest"}
RATIO_SCALE = 0.02
# From the warm start 15 + 6 L-BFGS iterations reach what the cold schedule reaches (the
# same mean error over held-out people, 2.94 against 2.95 %) in half the time.
# (iterations of the first round, of each polishing round with the landmarks found again,
# polishing rounds at most, tolerance on the loss change): from the warm start, and cold
WARM_SCHEDULE = ((15, 6), 1, 1e-4)
# from the amortised network's start (tryon.body.amortised): a few iterations, landmarks found once
QUICK_SCHEDULE = ((8, 0), 0, 1e-4)
# ... and half as many when only stature and weight are given (the network alone is then
# within a few millimetres of the full fit: tryon/body/data/amortised_fit.md)
QUICK_SCHEDULE_STATURE_WEIGHT = ((4, 0), 0, 1e-4)
COLD_SCHEDULE = ((30, 10), 2, 1e-5)
# tape name -> the prior's key, for the tapes the prior-guided fit aims at
PRIOR_TAPES = {"chest": "chest_cm", "waist_navel": "waist_navel_cm", "hip": "hip_cm", "neck": "neck_cm",
               "thigh": "thigh_cm", "crotch_height": "crotch_height_cm", "waist_height": "waist_height_cm",
               "shoulder_width": "shoulder_width_cm", "arm_length": "arm_length_cm", "wrist": "wrist_cm"}


class BodyFitError(TryonError):
    """Measurements that Anny cannot represent, or an inconsistent request."""


@dataclass
class Measurements:
    """What a user knows about a person. Give `weight_kg` or `bmi` (not both). Girths and
    lengths (cm) are those of `tryon.body.tape`: `waist_cm` is the natural waist, the
    smallest girth between ribs and hip bones; `waist_navel_cm` the waist at the navel."""

    height_cm: float
    gender: str = "female"
    weight_kg: float | None = None
    bmi: float | None = None
    age: float = 30.0
    chest_cm: float | None = None
    waist_cm: float | None = None
    hip_cm: float | None = None
    waist_navel_cm: float | None = None
    neck_cm: float | None = None
    thigh_cm: float | None = None
    crotch_height_cm: float | None = None
    shoulder_width_cm: float | None = None
    arm_length_cm: float | None = None
    waist_height_cm: float | None = None
    wrist_cm: float | None = None

    def target_bmi(self) -> float | None:
        if self.bmi is not None:
            return float(self.bmi)
        if self.weight_kg is None:
            return None
        return float(self.weight_kg) / (self.height_cm / 100.0) ** 2

    def girths(self) -> dict[str, float]:
        return {k: getattr(self, f"{k}_cm") for k in GIRTH_BANDS if getattr(self, f"{k}_cm") is not None}

    def tapes(self) -> dict[str, float]:
        """Every tape measurement given (cm), chest / waist / hip included."""
        out = self.girths()
        out.update({k: getattr(self, f"{k}_cm") for k in TAPE_RANGE_CM if getattr(self, f"{k}_cm") is not None})
        return out

    def validate(self) -> None:
        if self.gender not in GENDERS:
            raise BodyFitError(f"gender must be one of {sorted(GENDERS)}, got {self.gender!r}")
        names = ["height_cm", "weight_kg", "bmi", "age"] + [f"{k}_cm" for k in (*GIRTH_BANDS, *TAPE_RANGE_CM)]
        for name in names:
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
        for name, value in self.tapes().items():
            if name in TAPE_RANGE_CM:
                _check_range(name.replace("_", " "), value, TAPE_RANGE_CM[name], "cm")
        for name in ("crotch_height", "waist_height"):
            value = getattr(self, f"{name}_cm")
            if value is not None and value >= 0.75 * self.height_cm:
                raise BodyFitError(f"{name.replace('_', ' ')} {value:g} cm is not below three quarters of the "
                                   f"stature {self.height_cm:g} cm")


def _check_range(name: str, value: float, bounds: tuple[float, float], unit: str) -> None:
    if not bounds[0] <= value <= bounds[1]:
        raise BodyFitError(f"{name} {value:g} {unit} is outside the supported range {bounds[0]:g}-{bounds[1]:g} {unit}")


@dataclass
class BodyFit:
    """The fitted body, its parameters and the measurements asked, aimed at and achieved."""

    shape: BodyShape
    params: ShapeParams
    asked: dict[str, float]
    achieved: dict[str, float]
    iterations: int
    wall_s: float
    distortion: float = 0.0
    notes: list[str] = field(default_factory=list)
    prior: dict[str, float] = field(default_factory=dict)  # the prior's values the fit aimed at (cm)
    prior_sd: dict[str, float] = field(default_factory=dict)
    unknowns: np.ndarray | None = None  # the solver's variables at the answer (warm-start training)

    def report(self) -> dict:
        out = {
            "asked": self.asked,
            "achieved": self.achieved,
            "error": {k: self.achieved[k] - v for k, v in self.asked.items() if k in self.achieved},
            "params": self.params.to_dict(),
            "iterations": self.iterations,
            "wall_s": self.wall_s,
            "mesh_distortion": self.distortion,
        }
        if self.prior:
            out["prior"] = {"source": "ANSUR II (tryon.body.prior)", "aimed": self.prior, "sd": self.prior_sd}
        return out


def _logit(p: float) -> float:
    p = min(max(p, 1e-4), 1 - 1e-4)
    return math.log(p / (1 - p))


class _Problem:
    """Unknowns: logits of (weight, muscle, height, proportions) and atanh of local changes over
    their reach (`LOCAL_RANGE`).
    `groups` lists the local changes each unknown drives (the others stay 0); `targets` are
    tape measurements (m) with their residual scales (m), aimed at with landmarks found once
    per round."""

    def __init__(self, m: Measurements, groups: list[list[int]], targets: dict | None = None):
        self.m = m
        self.model = body_model()
        self.gender = GENDERS[m.gender]
        self.age = years_to_anny_age(m.age)
        self.target = {"height": m.height_cm / 100.0, "bmi": m.target_bmi()}
        self.groups = groups
        spread = torch.zeros(len(groups), len(LOCAL_CHANGES), dtype=DTYPE)
        reach = torch.tensor([LOCAL_RANGE.get(k, 1.0) if targets is not None else 1.0 for k in LOCAL_CHANGES],
                             dtype=DTYPE)
        for i, group in enumerate(groups):
            spread[i, group] = reach[group]
        self.spread = spread
        self.targets = targets  # None: the pinned fit on chest / waist / hip of `measure`
        self.girths = {k: v / 100.0 for k, v in m.girths().items()}
        self.landmarks: Landmarks | None = None

    def shape(self, z: torch.Tensor) -> BodyShape:
        w, mu, h, pr = torch.sigmoid(z[:4])
        ph = torch.stack([z.new_tensor(self.gender), z.new_tensor(self.age), mu, w, h, pr])[None]
        lc = (torch.tanh(z[4:]) @ self.spread)[None]
        return self.model.rest_shape(ShapeParams(gender=self.gender, age=self.age), phenotypes=ph, local=lc)

    def loss(self, z: torch.Tensor) -> torch.Tensor:
        s = self.shape(z)
        v = s.vertices
        height_scale = SCALE["height"] if self.targets is None else PRIOR_HEIGHT_SCALE
        r = [(stature(v) - self.target["height"]) / height_scale]
        if self.target["bmi"] is not None:
            r.append((bmi(v, s.faces) - self.target["bmi"]) / SCALE["bmi"])
        if self.targets is None:
            for name, value in self.girths.items():
                r.append((girth(s, name, v)[0] - value) / SCALE["girth"])
        else:
            if self.landmarks is None:
                self.landmarks = find_landmarks(s.detached())
            for name, (value, scale) in self.targets.items():
                r.append((tape(s, name, v, self.landmarks) - value) / scale)
        _, mu, _, pr = torch.sigmoid(z[:4])
        pull = torch.cat([(torch.stack([mu, pr]) - 0.5) / 0.5, torch.tanh(z[4:])]) / NEUTRAL_PULL
        return sum(x * x for x in r) + 0.25 * (pull * pull).sum()

    def initial(self) -> torch.Tensor:
        """Stature and BMI are nearly monotonic in the height and weight phenotypes: start
        from a linear interpolation of two probes each."""
        z = torch.zeros(4 + len(self.groups), dtype=DTYPE)
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


def prior_targets(m: Measurements, prior: AnthropometricPrior) -> tuple[dict[str, float], dict[str, float]]:
    """The prior's most likely value (cm) and sd of every `PRIOR_TAPES` measurement not
    given, conditioned on stature, sex, age, the weight and every measurement given."""
    known = {PRIOR_TAPES[k]: v for k, v in m.tapes().items() if k in PRIOR_TAPES}
    if m.target_bmi() is not None:
        known["weight_kg"] = m.target_bmi() * (m.height_cm / 100.0) ** 2
    pred = prior.predict(m.gender, m.height_cm, m.age, known)
    skip = set(m.tapes())
    if "waist" in skip:  # a natural waist given: the navel waist follows the body's own shape
        skip.add("waist_navel")
    mean = {k: pred.mean[key] for k, key in PRIOR_TAPES.items() if k not in skip}
    sd = {k: pred.sd[key] for k, key in PRIOR_TAPES.items() if k not in skip}
    return mean, sd


def _prior_scale(name: str, sd_cm: float) -> float:
    """Residual scale (m) of a measurement the prior predicts with spread `sd_cm`."""
    return PRIOR_SCALE_OF.get(name, PRIOR_SCALE * min(1.0, sd_cm / PRIOR_SD_REF))


def symmetric_groups() -> list[list[int]]:
    """One unknown per local change, left and right of `SYMMETRIC` sharing one."""
    index = {k: i for i, k in enumerate(LOCAL_CHANGES)}
    paired = {index[b]: index[a] for a, b in SYMMETRIC}
    return [[i] + [j for j, a in paired.items() if a == i] for i in range(len(LOCAL_CHANGES)) if i not in paired]


def _shape_ratio_targets(prob: _Problem, z: torch.Tensor, targets: dict) -> dict:
    """Targets for the tapes the survey does not measure (natural waist, underbust), unless
    asked: the ratio Anny's average shape of this stature and BMI has to a surveyed girth,
    times that girth's target, held loosely (2 cm)."""
    todo = {k: ref for k, ref in SHAPE_RATIOS.items() if k not in targets and ref in targets}
    if not todo:
        return {}
    with torch.no_grad():
        s = prob.shape(z)
        lm = find_landmarks(s)
        out = {}
        for name, ref in todo.items():
            ratio = float(tape(s, name, s.vertices, lm)) / float(tape(s, ref, s.vertices, lm))
            out[name] = (ratio * targets[ref][0], RATIO_SCALE)
    return out


def _solve(prob: _Problem, z: torch.Tensor, max_iter: int, evals: list[int], tolerance_change: float = 1e-9) -> torch.Tensor:
    z = z.detach().clone().requires_grad_(True)
    opt = torch.optim.LBFGS([z], lr=1.0, max_iter=max_iter, line_search_fn="strong_wolfe", tolerance_grad=1e-6,
                            tolerance_change=tolerance_change)

    def closure():
        opt.zero_grad()
        loss = prob.loss(z)
        loss.backward()
        evals[0] += 1
        return loss

    opt.step(closure)
    return z.detach()


def fit_body(m: Measurements, max_iter: int = 60, progress: bool = False, prior: bool | AnthropometricPrior = True,
             warm_start: bool = True, start: np.ndarray | None = None) -> BodyFit:
    """Solve Anny's shape for `m`; raises `BodyFitError` outside the supported range.
    `prior` (default: the shipped ANSUR II prior) fills in what `m` does not give;
    `prior=False` is the pinned fit of stature, BMI and chest / waist / hip alone.
    `warm_start` starts the prior-guided fit from `tryon.body.warmstart`'s prediction
    when the person's BMI is known (the same answer, found in fewer iterations). `start`:
    the unknowns to polish briefly instead (`tryon.body.amortised`'s prediction)."""
    m.validate()
    t0 = time.perf_counter()
    evals = [0]
    aimed: dict[str, float] = {}
    aimed_sd: dict[str, float] = {}
    if not isinstance(prior, (bool, AnthropometricPrior)):
        raise TypeError(f"prior must be True, False or an AnthropometricPrior, not {prior!r}")
    if prior is False:
        prob = _Problem(m, [[i] for i in range(LEGACY_LOCAL)])
        z = _solve(prob, prob.initial(), max_iter, evals)
    else:
        model = default_prior() if prior is True else prior
        aimed, aimed_sd = prior_targets(m, model)
        targets = {k: (v / 100.0, SCALE["girth"]) for k, v in m.tapes().items()}
        targets.update({k: (v / 100.0, _prior_scale(k, aimed_sd[k])) for k, v in aimed.items()})
        prob = _Problem(m, symmetric_groups(), targets=targets)
        z = prob.initial()
        targets.update(_shape_ratio_targets(prob, z, targets))  # on the cold start: Anny's average shape
        warm = None
        schedule = WARM_SCHEDULE
        if start is not None:
            if np.shape(start) != tuple(z.shape):
                raise BodyFitError(f"a start of {np.shape(start)} unknowns for a fit of {tuple(z.shape)}")
            warm = torch.as_tensor(np.asarray(start, np.float64))
            schedule = QUICK_SCHEDULE if m.tapes() else QUICK_SCHEDULE_STATURE_WEIGHT
        elif warm_start and m.target_bmi() is not None:
            from tryon.body.warmstart import initial_unknowns

            warm = initial_unknowns(m.gender, m.height_cm, m.target_bmi(), m.age, len(z))
        (first, polish), rounds, tol = schedule if warm is not None else COLD_SCHEDULE
        z = _solve(prob, z if warm is None else warm, first, evals, tol)
        for _ in range(rounds):  # find the landmarks again on the fitted body and polish
            before = prob.landmarks
            prob.landmarks = None
            with torch.no_grad():
                found = find_landmarks(prob.shape(z))
            if found.same_places(before):
                break
            prob.landmarks = found
            z = _solve(prob, z, polish, evals, tol)
    with torch.no_grad():
        shape = prob.shape(z).detached()
    w, mu, h, pr = (float(x) for x in torch.sigmoid(z[:4]))
    lc = (torch.tanh(z[4:]) @ prob.spread).numpy()
    params = ShapeParams(gender=prob.gender, age=prob.age, muscle=mu, weight=w, height=h, proportions=pr,
                         local={k: float(x) for k, x in zip(LOCAL_CHANGES, lc)})
    shape.params = params
    achieved = measurements(shape)
    if prior is not False:
        achieved.update({k: v for k, v in tape_measurements(shape).items() if k not in ("height_cm",)})
    asked = {"height_cm": m.height_cm}
    if m.target_bmi() is not None:
        asked["bmi"] = m.target_bmi()
    if m.weight_kg is not None:
        asked["weight_kg"] = m.weight_kg
    asked.update({f"{k}_cm": v for k, v in (m.tapes() if prior is not False else m.girths()).items()})
    fit = BodyFit(shape, params, asked, achieved, evals[0], time.perf_counter() - t0, distortion=mesh_distortion(shape),
                  prior={f"{k}_cm": v for k, v in aimed.items()}, prior_sd={f"{k}_cm": v for k, v in aimed_sd.items()},
                  unknowns=z.numpy().copy())
    tolerances = {"height_cm": 1.0, "bmi": 0.5, "chest_cm": 2.0, "waist_cm": 2.0, "hip_cm": 2.0}  # the pinned fit's
    if prior is not False:
        tolerances = {k: {"height_cm": 1.0, "bmi": 0.5, "weight_kg": 1.5}.get(k, 1.0) for k in asked}
    for key, tol in tolerances.items():
        if key in asked and key in achieved and abs(achieved[key] - asked[key]) > tol:
            fit.notes.append(f"{key}: asked {asked[key]:.1f}, achieved {achieved[key]:.1f} (Anny cannot reach it "
                             f"together with the other measurements)")
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
