"""Self-correction (dissertation ch. 6): a model trained on a small simulated set labels
many more bodies by its prediction refined by physics (seconds each, against tens of
seconds of simulation), and training again on both sets improves it for less time than
simulating as many drapes.

`tryon dataset refine --from DATA --model MODEL --count N --out DIR` makes a drape dataset
of its own: DATA's garment, sizes, fabric, body ranges and references (so the same
vertices), bodies drawn with another seed, and as ground truth `learned+refine`
(`tryon.learn.refine`) instead of a simulated drape. Every body trains, except those at or
above DATA's extrapolation BMI, which stay held out. It is made, sharded and resumed by
the dataset generator like any other. `tryon train drape --data DATA DIR` trains on both;
validation and test remain DATA's simulated bodies."""

from __future__ import annotations

import copy
import hashlib
import shutil
import time
from pathlib import Path

import numpy as np

from tryon.dataset.bodies import BodyRanges, sample_body
from tryon.dataset.drapes import KIND, sample_header, unit_of
from tryon.dataset.generate import RunReport, open_dataset, run_generator
from tryon.dataset.store import Manifest, ShardStore, software_version
from tryon.errors import TryonError

REFINED_SEED_OFFSET = 1000  # default seed: the source's plus this, so no body repeats the source's draws
REFINED_SPLIT_RULE = ("refined drapes all train, except bodies at or above extrapolation_bmi (held out); "
                      "validation and test are the simulated source's")


def model_digest(path: str | Path) -> str:
    return hashlib.sha1(Path(path).read_bytes()).hexdigest()[:12]


def refined_manifest(source: Manifest, model_path: str | Path, count: int, seed: int | None = None) -> Manifest:
    """The manifest of a refined set drawn like `source`: `count` bodies in every size."""
    if not 1 <= count <= 1_000_000:
        raise TryonError(f"--count {count}: give 1 to 1,000,000 bodies")
    if source.kind != KIND:
        raise TryonError(f"the source holds a {source.kind!r} dataset, not drapes")
    spec = copy.deepcopy(source.spec)
    spec["truth"] = {"method": "learned+refine", "model_sha1": model_digest(model_path),
                     "source_seed": source.seed, "source_software": source.software_version}
    split = {"rule": REFINED_SPLIT_RULE, "train": 1.0, "val": 0.0,
             "extrapolation_bmi": source.split["extrapolation_bmi"]}
    return Manifest(KIND, source.generator_version, software_version(), source.seed + REFINED_SEED_OFFSET if seed is None else seed,
                    count * len(spec["sizes"]), source.shard_size, spec, split, created=time.strftime("%Y-%m-%dT%H:%M:%S%z"))


def make_refined_dataset(source_dir: str | Path, model_path: str | Path, count: int, out: str | Path,
                         seed: int | None = None, workers: int = 1, ray_address: str | None = None, force: bool = False,
                         progress: bool = True, limit: int | None = None) -> tuple[ShardStore, RunReport]:
    """Make (or resume) the refined set in `out`; see the module docstring."""
    from tryon.learn.model import DrapeModel

    source_dir = Path(source_dir)
    source = Manifest.read(source_dir)
    model = DrapeModel.load(model_path)
    model.check_dataset(source.spec)
    store = open_dataset(out, refined_manifest(source, model_path, count, seed), force=force)
    refs = store.folder / "references"
    if not refs.exists():
        shutil.copytree(source_dir / "references", refs)

    def prepare(manifest: Manifest, folder: Path):
        return str(Path(model_path).resolve())

    report = run_generator(store, prepare, refined_unit, workers=workers, ray_address=ray_address, progress=progress,
                           limit=limit)
    return store, report


_MODELS: dict[str, object] = {}  # per process (a Ray worker loads the model once)
_LAST_BODY: dict[tuple[int, int], object] = {}  # a body's units are consecutive: fit it once for all its sizes


def _body(manifest: Manifest, body_index: int):
    key = (manifest.seed, body_index)
    if key not in _LAST_BODY:
        _LAST_BODY.clear()
        _LAST_BODY[key] = sample_body(manifest.seed, body_index, BodyRanges.from_dict(manifest.spec["ranges"]))
    return _LAST_BODY[key]


def refined_unit(manifest: Manifest, model_path: str, unit: int) -> dict[str, np.ndarray]:
    """One (body, size) unit: the model's prediction on the sampled body, refined."""
    from tryon.dataset.drapes import unit_fabric
    from tryon.drape.fit_metrics import face_strain, penetration
    from tryon.learn.features import a_posed_body
    from tryon.learn.model import DrapeModel
    from tryon.learn.refine import refine_drape
    from tryon.sim.model import ClothModel

    t0 = time.perf_counter()
    if model_path not in _MODELS:
        _MODELS[model_path] = DrapeModel.load(model_path)
    model = _MODELS[model_path]
    spec = manifest.spec
    body_index, size = unit_of(manifest, unit)
    body = _body(manifest, body_index)
    out = sample_header(manifest, body, size, unit)
    target = a_posed_body(body.params)
    garment = model.reference_garment(body.gender, size)
    fabric, fabric_record = unit_fabric(manifest, unit)  # drawn per unit as for the simulated drapes
    if spec.get("fabrics"):
        out.update(fabric_record)
    pred = model.predict_vertices(target.vertices, body.gender, size, fabric)
    try:
        x, stats = refine_drape(pred, garment, target, fabric)
    except TryonError as exc:  # e.g. a predicted triangle collapsed: the sample is recorded as failed
        out.update({"x": np.full(pred.shape, np.nan, np.float32), "ok": np.asarray(False),
                    "error": np.asarray(str(exc)[:500]), "wall_s": np.asarray(time.perf_counter() - t0)})
        return out
    pen = penetration(x, target.vertices, target.faces)
    strain = face_strain(ClothModel(garment.cloth_mesh(), fabric), x)
    good = stats["start_self_crossings"] == 0 and pen["penetration_pct"] == 0.0 and np.all(np.isfinite(x))
    out.update({"x": x.astype(np.float32), "ok": np.asarray(bool(good)),
                "error": np.asarray("" if good else f"refined drape crosses itself ({stats['start_self_crossings']}) "
                                    f"or the body ({pen['penetration_pct']:.2f} %)"),
                "settled": np.asarray(bool(stats["refine_final_speed"] <= 0.02)),
                "final_rest_speed": np.asarray(float(stats["refine_final_speed"])),
                "steps": np.asarray(int(stats["refine_steps"])), "penetration_pct": np.asarray(pen["penetration_pct"]),
                "max_strain": np.asarray(float(strain.max())), "wall_s": np.asarray(time.perf_counter() - t0)})
    return out
