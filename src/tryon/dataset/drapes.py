"""Drape datasets: one garment, several sizes, many bodies, each drape what `tryon
drape` gives for that body, size and fabric.

The garment of each (gender, size) is drafted on the size's fit model and dressed on it
once (`references`); every size shares one triangulation (`transfer_mesh`), so the
garment has the same vertices in every sample. A sample then samples its body directly
in measurement space (`bodies.sample_body`, no body fit), poses it in the A-pose and runs
the drape stage as `tryon drape` does (`simulate_drape`: the fit model morphs into the
body under the garment, then the garment settles), with `DATASET_DRAPE`'s settings.

Unit u is body u // len(sizes) in size sizes[u % len(sizes)]: every body is draped in
every size.
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
from tryon.garment.drafts import GARMENTS, draft
from tryon.garment.sizes import SIZES
from tryon.garment.triangulate import transfer_mesh, triangulate_pattern

KIND = "drape"
# 2: tops are sewn with self-collision from sleeves placed clear of the bodice (dressing
# v16), so their drapes differ from version 1's (data/tshirt-v1 was made with version 1)
GENERATOR_VERSION = 2
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

    def manifest(self, software_version: str) -> Manifest:
        self.validate()
        spec = {"garment": self.garment, "sizes": list(self.sizes), "fabric": self.fabric,
                "topology": {"gender": self.topology[0], "size": self.topology[1].upper()},
                "edge_length": self.edge_length, "ranges": self.ranges.to_dict(),
                "drape": {k: v for k, v in asdict(DrapeRequest(Measurements(height_cm=170, weight_kg=70),
                                                                    **DATASET_RECORDED)).items() if k not in
                          ("body", "garment", "size", "fabric", "edge_length", "print_image", "print_width_cm")
                          + DRAPE_FIXED}}
        split = {"rule": "by body: extrapolation if BMI >= extrapolation_bmi, else train / val / test drawn per body "
                         "from the seed", "train": self.train_fraction, "val": self.val_fraction,
                 "extrapolation_bmi": self.extrapolation_bmi}
        return Manifest(KIND, GENERATOR_VERSION, software_version, self.seed, self.count * len(self.sizes),
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
    sizes = manifest.spec["sizes"]
    return unit // len(sizes), sizes[unit % len(sizes)]


def drape_unit(manifest: Manifest, refs: dict[tuple[str, str], Reference], unit: int) -> dict[str, np.ndarray]:
    """The drape of one (body, size) unit as a flat dict of arrays (see `SAMPLE_KEYS`)."""
    from tryon.drape.fit_metrics import face_strain, penetration

    t0 = time.perf_counter()
    spec = manifest.spec
    body_index, size = unit_of(manifest, unit)
    body = sample_body(manifest.seed, body_index, BodyRanges.from_dict(spec["ranges"]))
    ref = refs[(body.gender, size)]
    shape = body.shape()
    target = posed_body(shape, "a", drafting_measurements(shape)["crotch_height"])
    req = DrapeRequest(body.measurements(), garment=spec["garment"], size=size, fabric=spec["fabric"], edge_length=spec["edge_length"],
                       **spec["drape"], **DATASET_DRAPE)
    n = len(ref.garment.vertices)
    out = sample_header(manifest, body, size, unit)
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
    body_index, _ = unit_of(manifest, unit)
    return {"body": np.asarray(body_index), "size": np.asarray(manifest.spec["sizes"].index(size)),
            "gender": np.asarray(GENDER_CODE[body.gender]), "height_cm": np.asarray(body.height_cm),
            "bmi": np.asarray(body.bmi), "shape_params": shape_vector(body.params),
            "split": np.asarray(split_of(manifest, body_index, body.bmi)),
            "settled": np.asarray(False), "final_rest_speed": np.asarray(np.inf), "steps": np.asarray(0),
            "penetration_pct": np.asarray(np.nan), "max_strain": np.asarray(np.nan)}
