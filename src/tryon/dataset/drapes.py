"""Drape datasets: one garment, several sizes, many bodies, each drape what `tryon
drape` gives for that body, size and fabric.

The garment of each (gender, size) is drafted on the size's fit model and dressed on it
once (`references`); every size shares one triangulation (`transfer_mesh`), so the
garment has the same vertices in every sample. A sample then samples its body directly
in measurement space (`bodies.sample_body`, no body fit), poses it in the A-pose and runs
the drape stage as `tryon drape` does (`simulate_drape`: the fit model morphs into the
body under the garment, then the garment settles), with `DATASET_DRAPE`'s settings.

Unit u is body u // n in the (u % n)-th of its n sizes: every size (n = len(sizes)), or,
with `size_window`, the n sizes around the body's own (one smaller, its own, then larger:
the drapes a size recommendation compares, without the hopeless ones that fail after
minutes). With `fabrics`, each unit's fabric is drawn from them, or, with probability
`fabric_mix`, blended between two of them (`tryon.fabric.blend`); the references stay
dressed in `fabric`.
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from tryon.body.anny_model import LEGACY_LOCAL_CHANGES, LOCAL_CHANGES, PHENOTYPES, ShapeParams, body_model
from tryon.body.fit import Measurements, fit_body
from tryon.body.measure import drafting_measurements
from tryon.body.pose import BodyPose, posed_body
from tryon.dataset.bodies import BodyRanges, BodySample, sample_body
from tryon.dataset.store import DatasetError, Manifest
from tryon.drape.dress import DressedGarment, dress_cached
from tryon.drape.pipeline import DrapeRequest, fit_model_measurements, simulate_drape
from tryon.errors import TryonError
from tryon.fabric import load_fabric
from tryon.fabric.base import Fabric
from tryon.fabric.blend import blend_fabrics, fabric_features
from tryon.fabric.wang2011 import WangFabric
from tryon.garment.drafts import GARMENTS, draft
from tryon.garment.sizes import SIZES
from tryon.garment.triangulate import transfer_mesh, triangulate_pattern

KIND = "drape"
# 3: the fabric drawn per drape and the window of sizes around each body's own (specs
# without `fabrics` and `size_window` make version 2's samples and keep its number, so the
# datasets in git resume)
GENERATOR_VERSION = 3
# 2: tops are sewn with self-collision from sleeves placed clear of the bodice (dressing
# v16), so their drapes differ from version 1's (data/tshirt-v1 was made with version 1)
GENERATOR_VERSION_FIXED_FABRIC = 2
GENDER_CODE = {"male": 0, "female": 1}
# Drape settings a dataset fixes instead of recording: samples settle with the morph's step
# throughout, as generator version 2 did (`tryon drape` has since settled with longer steps
# to the same rest). `allow_tight` belongs to `tryon drape`'s size check, which a dataset's
# drape stage does not run. Their morphs are paced by the whole body, as version 2's were,
# and a sample's outcome does not depend on how fast the machine is (no time limit).
DATASET_DRAPE = {"settle_dt_ratio": 1.0, "morph_whole_body": True, "time_limit_s": math.inf}
# ... and settings a dataset records in its manifest, with the values generator 2 used
DATASET_RECORDED = {"max_settle_time": 1.5}
DRAPE_FIXED = ("allow_tight", *DATASET_DRAPE)


@dataclass
class DrapeDatasetSpec:
    """What a drape dataset holds. `count` bodies, each draped in every size."""

    garment: str = "tshirt"
    sizes: tuple[str, ...] = ("S", "M", "L")
    count: int = 100
    fabric: str = "gray-interlock"
    edge_length: float = 0.012
    seed: int = 0
    ranges: BodyRanges = field(default_factory=BodyRanges)
    shard_size: int = 32
    train_fraction: float = 0.8
    val_fraction: float = 0.1
    extrapolation_bmi: float = 40.0  # bodies at or above this BMI form the extrapolation split
    # the (gender, size) whose triangulation every size shares: datasets with the same
    # garment, edge length and topology have the same vertices and can be trained on together
    topology: tuple[str, str] = ("female", "M")
    # the fabric of each drape drawn from these presets (None: every drape in `fabric`) ...
    fabrics: tuple[str, ...] | None = None
    # ... or, with this probability, blended between two of them
    fabric_mix: float = 0.0
    # drape each body in this many sizes around its own instead of in every size
    size_window: int | None = None

    def validate(self) -> None:
        if self.garment not in GARMENTS:
            raise TryonError(f"unknown garment {self.garment!r}; datasets drape one of {', '.join(GARMENTS)}")
        self.sizes = tuple(s.upper() for s in self.sizes)
        bad = [s for s in self.sizes if s not in SIZES]
        if bad or not self.sizes or len(set(self.sizes)) != len(self.sizes):
            raise TryonError(f"sizes {list(self.sizes)}: give distinct standard sizes ({', '.join(SIZES)})")
        if not 1 <= self.count <= 1_000_000:
            raise TryonError(f"--count {self.count}: give 1 to 1,000,000 bodies")
        if not 0.006 <= self.edge_length <= 0.05:
            raise TryonError(f"edge length {self.edge_length} m is outside 0.006-0.05 m")
        if self.topology[0] not in GENDER_CODE or self.topology[1].upper() not in SIZES:
            raise TryonError(f"topology {self.topology}: give a gender and a standard size, e.g. ('female', 'M')")
        if not 1 <= self.shard_size <= 4096:
            raise TryonError(f"shard size {self.shard_size} is outside 1-4096 samples")
        if not (0 < self.train_fraction and 0 <= self.val_fraction and self.train_fraction + self.val_fraction < 1):
            raise TryonError("train and validation fractions must be positive and leave room for a test split")
        load_fabric(self.fabric)
        for name in (self.fabric, *(self.fabrics or ())):
            if "+" in name or "@" in name:  # the samples name a blend a+b@t (recorded_fabric_names)
                raise TryonError(f"fabric {name!r}: a dataset's fabric names may not hold '+' or '@'")
        if self.fabrics is not None:
            self.fabrics = tuple(self.fabrics)
            if not self.fabrics or len(set(self.fabrics)) != len(self.fabrics):
                raise TryonError(f"fabrics {list(self.fabrics)}: give distinct measured presets")
            for name in self.fabrics:
                if not isinstance(load_fabric(name), WangFabric):
                    raise TryonError(f"fabric {name!r}: a dataset draws measured presets (Wang 2011) only")
        if not 0.0 <= self.fabric_mix <= 1.0 or (self.fabric_mix and len(self.fabrics or ()) < 2):
            raise TryonError(f"fabric mix {self.fabric_mix}: give a probability in 0-1 and at least two --fabrics to blend")
        if self.size_window is not None and not 1 <= self.size_window <= len(self.sizes):
            raise TryonError(f"size window {self.size_window}: give 1 to {len(self.sizes)} (the sizes listed)")
        first = SIZES.index(self.sizes[0])
        if self.size_window is not None and list(self.sizes) != list(SIZES[first:first + len(self.sizes)]):
            raise TryonError(f"sizes {list(self.sizes)}: a size window needs consecutive sizes in order ({', '.join(SIZES)})")

    def units_per_body(self) -> int:
        return self.size_window or len(self.sizes)

    def manifest(self, software_version: str) -> Manifest:
        self.validate()
        spec = {"garment": self.garment, "sizes": list(self.sizes), "fabric": self.fabric,
                "topology": {"gender": self.topology[0], "size": self.topology[1].upper()},
                "edge_length": self.edge_length, "ranges": self.ranges.to_dict(),
                "drape": {k: v for k, v in asdict(DrapeRequest(Measurements(height_cm=170, weight_kg=70),
                                                                    **DATASET_RECORDED)).items() if k not in
                          ("body", "garment", "size", "fabric", "edge_length", "print_image", "print_width_cm")
                          + DRAPE_FIXED}}
        drawn = {k: v for k, v in (("fabrics", list(self.fabrics) if self.fabrics else None),
                                   ("fabric_mix", self.fabric_mix or None), ("size_window", self.size_window)) if v}
        spec.update(drawn)
        split = {"rule": "by body: extrapolation if BMI >= extrapolation_bmi, else train / val / test drawn per body "
                         "from the seed", "train": self.train_fraction, "val": self.val_fraction,
                 "extrapolation_bmi": self.extrapolation_bmi}
        version = GENERATOR_VERSION if drawn else GENERATOR_VERSION_FIXED_FABRIC
        return Manifest(KIND, version, software_version, self.seed, self.count * self.units_per_body(),
                        self.shard_size, spec, split, created=time.strftime("%Y-%m-%dT%H:%M:%S%z"))


def split_of(manifest: Manifest, body: int, bmi: float) -> str:
    """The split of a body, fixed by the manifest before any training."""
    rule = manifest.split
    limit = rule.get("extrapolation_bmi")  # None: no extrapolation split
    if limit is not None and bmi >= limit:
        return "extrapolation"
    r = np.random.default_rng([manifest.seed, body, 7]).random()
    return "train" if r < rule["train"] else "val" if r < rule["train"] + rule["val"] else "test"


# ----------------------------------------------------------------------------- references
@dataclass
class Reference:
    """A size's garment dressed on its fit model, and that model's A-posed body."""

    gender: str
    size: str
    params: ShapeParams
    garment: DressedGarment
    start: BodyPose | None = None

    def pose(self) -> BodyPose:
        if self.start is None:
            shape = body_model().rest_shape(self.params)
            self.start = posed_body(shape, "a", drafting_measurements(shape)["crotch_height"])
        return self.start


def reference_path(folder: Path, gender: str, size: str) -> Path:
    return folder / "references" / f"{gender}-{size}.npz"


def build_references(manifest: Manifest, folder: Path, progress: bool = True) -> dict[tuple[str, str], Reference]:
    """Dress the garment of every (gender, size) on its fit model, all sizes on one
    triangulation (that of the first gender's middle size); kept in `folder/references`."""
    spec = manifest.spec
    ranges = BodyRanges.from_dict(spec["ranges"])
    fabric = load_fabric(spec["fabric"])
    index_path = folder / "references" / "references.json"
    known = json.loads(index_path.read_text()) if index_path.exists() else {}
    refs: dict[tuple[str, str], Reference] = {}
    base = _base_mesh(spec)
    for gender, size in [(g, s) for g in ranges.genders for s in spec["sizes"]]:
        key = f"{gender}-{size}"
        path = reference_path(folder, gender, size)
        if key in known and path.exists():
            refs[(gender, size)] = Reference(gender, size, ShapeParams.from_dict(known[key]["params"]), DressedGarment.load(path))
            continue
        if progress:
            print(f"reference drape: {spec['garment']} {size} on the {gender} fit model", flush=True)
        fit, m, pattern = size_pattern(spec["garment"], gender, size)
        mesh = transfer_mesh(base, pattern)
        start = posed_body(fit.shape, "a", m["crotch_height"])
        garment = dress_cached(pattern, start, fabric, spec["edge_length"], progress=False, mesh=mesh)
        if garment.stats.get("self_intersections", 0):
            raise DatasetError(f"the {spec['garment']} {size} dressed on the {gender} fit model crosses itself "
                               f"({garment.stats['self_intersections']} edge-triangle pairs), so every drape in that size "
                               "would be refused; leave that size out")
        path.parent.mkdir(parents=True, exist_ok=True)
        garment.save(path)
        known[key] = {"params": fit.params.to_dict(), "dress_stats": garment.stats}
        index_path.write_text(json.dumps(known, indent=1, default=float))
        refs[(gender, size)] = Reference(gender, size, fit.params, garment, start)
    faces = {k: r.garment.faces.tobytes() for k, r in refs.items()}
    if len(set(faces.values())) != 1:
        raise DatasetError(f"the reference garments in {folder / 'references'} do not share one topology; "
                           "remove that folder and run again")
    return refs


def size_pattern(garment: str, gender: str, size: str):
    """The fit model of a standard size, its drafting measurements and the garment's pattern."""
    req = DrapeRequest(Measurements(height_cm=170, weight_kg=70, gender=gender), garment=garment, size=size)
    fit = fit_body(fit_model_measurements(req), prior=False)  # pinned, as in tryon drape
    m = drafting_measurements(fit.shape)
    return fit, m, draft(garment, m, size=size, meta={"gender": gender})


def _base_mesh(spec: dict):
    """The triangulation every size shares: the topology size's own, at the edge length."""
    _, _, pattern = size_pattern(spec["garment"], spec["topology"]["gender"], spec["topology"]["size"])
    return triangulate_pattern(pattern, spec["edge_length"])


# ----------------------------------------------------------------------------- samples
def unit_of(manifest: Manifest, unit: int) -> tuple[int, str]:
    """(body, size) of a unit of a dataset that drapes every body in every size."""
    if manifest.spec.get("size_window"):
        raise DatasetError("this dataset drapes each body in the sizes around its own: use unit_body")
    sizes = manifest.spec["sizes"]
    return unit // len(sizes), sizes[unit % len(sizes)]


# what decides a body's own size: the chest for tops, the hip for trousers and skirts, the
# larger of the two for the dress
SIZE_GIRTHS = {"tshirt": ("chest",), "longsleeve": ("chest",), "trousers": ("hip",), "skirt": ("hip",),
               "dress": ("chest", "hip")}


def own_size_index(garment: str, gender: str, m: dict) -> int:
    """The index in `SIZES` of the size whose chart girths lie nearest the body's
    (`drafting_measurements`, metres)."""
    from tryon.garment.sizes import size_measurements

    best = 0
    for girth in SIZE_GIRTHS[garment]:
        body_cm = 100.0 * m[f"{girth}_girth"]
        chart = [size_measurements(s, gender)[f"{girth}_cm"] for s in SIZES]
        best = max(best, int(np.argmin([abs(body_cm - c) for c in chart])))
    return best


def window_sizes(garment: str, gender: str, m: dict, sizes: list[str], window: int) -> list[str]:
    """The `window` consecutive sizes of `sizes` from one below the body's own size, shifted
    to stay inside the list."""
    own = own_size_index(garment, gender, m) - SIZES.index(sizes[0])
    first = min(max(own - 1, 0), len(sizes) - window)
    return list(sizes[first:first + window])


@dataclass
class UnitBody:
    """The body of a unit, A-posed as `tryon drape` poses it, and the unit's size."""

    index: int
    sample: BodySample
    target: BodyPose
    size: str


def unit_body(manifest: Manifest, unit: int) -> UnitBody:
    spec = manifest.spec
    window = spec.get("size_window")
    n = window or len(spec["sizes"])
    body = sample_body(manifest.seed, unit // n, BodyRanges.from_dict(spec["ranges"]))
    shape = body.shape()
    m = drafting_measurements(shape)
    sizes = window_sizes(spec["garment"], body.gender, m, spec["sizes"], window) if window else spec["sizes"]
    return UnitBody(unit // n, body, posed_body(shape, "a", m["crotch_height"]), sizes[unit % n])


def unit_fabric(manifest: Manifest, unit: int) -> tuple[Fabric, dict[str, np.ndarray]]:
    """The fabric of a unit and what a sample records of it: the indices into the spec's
    `fabrics` of the two fabrics blended (the same twice when none is), the weight of the
    second, and `tryon.fabric.blend.fabric_features`."""
    spec = manifest.spec
    names = spec.get("fabrics")
    if not names:
        fabric = load_fabric(spec["fabric"])
        return fabric, {"fabric_features": fabric_features(fabric)}
    rng = np.random.default_rng([manifest.seed, unit, 13])
    a = int(rng.integers(len(names)))
    b, t = a, 0.0
    if rng.random() < spec.get("fabric_mix", 0.0):
        b = int((a + 1 + rng.integers(len(names) - 1)) % len(names))
        t = round(float(rng.uniform(0.0, 1.0)), 3)
    fabric = load_fabric(names[a]) if b == a else blend_fabrics(load_fabric(names[a]), load_fabric(names[b]), t)
    return fabric, {"fabric_a": np.asarray(a), "fabric_b": np.asarray(b), "fabric_t": np.asarray(t, np.float32),
                    "fabric_features": fabric_features(fabric)}


BLENDED = "blended"  # what a blend of two measured fabrics is reported as


def recorded_fabric_names(spec: dict, arrays: dict[str, np.ndarray]) -> np.ndarray:
    """[S] the name of each sample's fabric, read from what `unit_fabric` recorded: the
    dataset's one fabric, the measured fabric drawn, or a blend's `a+b@t` (`blend_fabrics`)."""
    names = spec.get("fabrics")
    if not names or "fabric_a" not in arrays:
        return np.full(len(arrays["unit"]), spec["fabric"])
    a, b, t = arrays["fabric_a"].astype(int), arrays["fabric_b"].astype(int), arrays["fabric_t"]
    return np.asarray([names[i] if i == j else f"{names[i]}+{names[j]}@{float(w):.3f}" for i, j, w in zip(a, b, t)])


def fabric_named(name: str) -> Fabric:
    """The fabric a recorded name (`recorded_fabric_names`) stands for."""
    if "+" in name:
        pair, t = name.rsplit("@", 1)
        a, b = pair.split("+", 1)
        return blend_fabrics(load_fabric(a), load_fabric(b), float(t))
    return load_fabric(name)


def fabric_group(name: str) -> str:
    """How results report a recorded fabric: the measured fabric by name, a blend as `blended`."""
    return BLENDED if "+" in name else str(name)


def drape_unit(manifest: Manifest, refs: dict[tuple[str, str], Reference], unit: int) -> dict[str, np.ndarray]:
    """The drape of one (body, size) unit as a flat dict of arrays (see `SAMPLE_KEYS`)."""
    from tryon.drape.fit_metrics import face_strain, penetration

    t0 = time.perf_counter()
    spec = manifest.spec
    unit_b = unit_body(manifest, unit)
    body, size, target = unit_b.sample, unit_b.size, unit_b.target
    ref = refs[(body.gender, size)]
    fabric, fabric_record = unit_fabric(manifest, unit)
    drawn = spec.get("fabrics")  # a drawn fabric travels as its data; a fixed one by name, as before
    req = DrapeRequest(body.measurements(), garment=spec["garment"], size=size,
                       fabric=fabric.to_arcsim_dict() if drawn else spec["fabric"], edge_length=spec["edge_length"],
                       **spec["drape"], **DATASET_DRAPE)
    n = len(ref.garment.vertices)
    out = sample_header(manifest, body, size, unit)
    if drawn:
        out.update(fabric_record)
    try:
        x, _, _, stats, solver = simulate_drape(req, ref.garment, ref.pose(), target, progress=False)
    except TryonError as exc:  # the sample is recorded as failed; the dataset goes on
        out.update({"x": np.full((n, 3), np.nan, np.float32), "ok": np.asarray(False), "error": np.asarray(str(exc)[:500])})
        out["wall_s"] = np.asarray(time.perf_counter() - t0)
        return out
    pen = penetration(x, target.vertices, target.faces)
    strain = face_strain(solver.model, x)
    out.update({"x": x.astype(np.float32), "ok": np.asarray(True), "error": np.asarray(""),
                "settled": np.asarray(bool(stats["settled"])), "final_rest_speed": np.asarray(float(stats["final_rest_speed"])),
                "steps": np.asarray(int(stats["steps"])), "penetration_pct": np.asarray(pen["penetration_pct"]),
                "max_strain": np.asarray(float(strain.max())), "wall_s": np.asarray(time.perf_counter() - t0)})
    return out


def shape_vector(params: ShapeParams) -> np.ndarray:
    """Anny's phenotypes (PHENOTYPES order) then local changes (LOCAL_CHANGES order). The
    controls appended after the first `LEGACY_LOCAL_CHANGES` are left out when all zero
    (the pinned bodies of the datasets): their vectors keep the length stored in git."""
    local = params.local_tensor()[0].numpy()
    if not local[LEGACY_LOCAL_CHANGES:].any():
        local = local[:LEGACY_LOCAL_CHANGES]
    return np.concatenate([params.phenotype_tensor()[0].numpy(), local])


def shape_params(vector: np.ndarray) -> ShapeParams:
    """The inverse of `shape_vector`."""
    ph = dict(zip(PHENOTYPES, (float(v) for v in vector[:len(PHENOTYPES)])))
    return ShapeParams(**ph, local=dict(zip(LOCAL_CHANGES, (float(v) for v in vector[len(PHENOTYPES):]))))


def sample_header(manifest: Manifest, body: BodySample, size: str, unit: int) -> dict[str, np.ndarray]:
    return {"body": np.asarray(body.index), "size": np.asarray(manifest.spec["sizes"].index(size)),
            "gender": np.asarray(GENDER_CODE[body.gender]), "height_cm": np.asarray(body.height_cm),
            "bmi": np.asarray(body.bmi), "shape_params": shape_vector(body.params),
            "split": np.asarray(split_of(manifest, body.index, body.bmi)),
            "settled": np.asarray(False), "final_rest_speed": np.asarray(np.inf), "steps": np.asarray(0),
            "penetration_pct": np.asarray(np.nan), "max_strain": np.asarray(np.nan)}
