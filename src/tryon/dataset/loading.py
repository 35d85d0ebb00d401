"""Making and reading drape datasets as a whole."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from tryon.dataset import drapes
from tryon.dataset.drapes import DrapeDatasetSpec, Reference, build_references, drape_unit
from tryon.dataset.generate import RunReport, open_dataset, run_generator
from tryon.dataset.store import DatasetError, Manifest, ShardStore, sample_rows, software_version
from tryon.drape.dress import DressedGarment
from tryon.fabric import load_fabric
from tryon.fabric.blend import fabric_features


def make_drape_dataset(spec: DrapeDatasetSpec, out: str | Path, workers: int = 1, ray_address: str | None = None,
                       force: bool = False, progress: bool = True, limit: int | None = None) -> tuple[ShardStore, RunReport]:
    """Make (or resume) a drape dataset in `out`."""
    store = open_dataset(out, spec.manifest(software_version()), force=force)
    report = run_generator(store, _prepare, drape_unit, workers=workers, ray_address=ray_address, progress=progress,
                           limit=limit)
    return store, report


def _prepare(manifest: Manifest, folder: Path) -> dict:
    return build_references(manifest, folder)


@dataclass
class DrapeDataset:
    """A drape dataset in memory: one row per (body, size) sample."""

    manifest: Manifest
    arrays: dict[str, np.ndarray]
    faces: np.ndarray                      # [F,3], shared by every sample
    references: dict[tuple[str, str], DressedGarment]

    def __len__(self) -> int:
        return len(self.arrays["unit"])

    def rows(self, split: str | None = None, ok_only: bool = True) -> np.ndarray:
        return sample_rows(self.arrays, split, ok_only)

    def summary(self) -> dict:
        a = self.arrays
        ok = a["ok"].astype(bool)
        return {"samples": len(self), "ok": int(ok.sum()), "settled": int((a["settled"].astype(bool) & ok).sum()),
                "splits": {str(s): int((a["split"] == s).sum()) for s in np.unique(a["split"])},
                "bmi": [float(a["bmi"].min()), float(a["bmi"].max())],
                "height_cm": [float(a["height_cm"].min()), float(a["height_cm"].max())],
                "mean_wall_s": float(a["wall_s"].mean()), "max_penetration_pct": float(np.nanmax(a["penetration_pct"])) if ok.any() else None}


def load_drape_dataset(folder: str | Path) -> DrapeDataset:
    folder = Path(folder)
    manifest = Manifest.read(folder)
    if manifest.kind != drapes.KIND:
        raise DatasetError(f"{folder} holds a {manifest.kind!r} dataset, not drapes")
    store = ShardStore(folder, manifest)
    arrays = _with_fabric_arrays(manifest.spec, store.load())
    refs = reference_garments(folder)
    faces = next(iter(refs.values())).faces
    return DrapeDataset(manifest, arrays, faces, refs)


def _with_fabric_arrays(spec: dict, arrays: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """The arrays with each sample's fabric by name (`fabric_name`) and, where the dataset
    did not record them (one fabric, made before fabrics were recorded), its features."""
    arrays["fabric_name"] = drapes.recorded_fabric_names(spec, arrays)
    if "fabric_features" not in arrays:
        one = fabric_features(load_fabric(spec["fabric"]))
        arrays["fabric_features"] = np.repeat(one[None], len(arrays["unit"]), 0)
    return arrays


def reference_garments(folder: str | Path) -> dict[tuple[str, str], DressedGarment]:
    """The dataset's dressed garments per (gender, size): every sample shares their mesh."""
    refs = {}
    for p in sorted((Path(folder) / "references").glob("*-*.npz")):
        gender, size = p.stem.split("-", 1)
        refs[(gender, size)] = DressedGarment.load(p)
    if not refs:
        raise DatasetError(f"{folder}/references holds no reference garments; the dataset is incomplete")
    return refs


UNIT_STRIDE = 100_000_000  # the k-th merged dataset's units (and bodies) are offset by k times this
REQUIRED_KEYS = {"unit", "body", "x", "ok", "split", "gender", "size", "shape_params", "settled", "wall_s",
                 "penetration_pct", "bmi", "height_cm"}


def load_drape_datasets(folders: list[str | Path]) -> DrapeDataset:
    """Several drape datasets of one garment topology trained on together (a simulated set
    and the refined drapes of `tryon dataset refine`): the first one's samples and the
    others' training samples in one table, units and bodies offset per dataset so they stay
    distinct; the first one's references and manifest, the others' manifests in
    `manifest.notes["merged"]`."""
    import copy

    sets = [load_drape_dataset(f) for f in folders]
    if len(sets) == 1:
        return sets[0]
    first = sets[0]
    same = ("garment", "sizes", "edge_length", "topology", "fabric")
    for f, d in zip(folders[1:], sets[1:]):
        diff = [k for k in same if d.manifest.spec.get(k) != first.manifest.spec.get(k)]
        if diff or d.faces.shape != first.faces.shape or not np.array_equal(d.faces, first.faces):
            raise DatasetError(f"{f} cannot be trained on with {folders[0]}: "
                               f"{', '.join(diff) if diff else 'the garment topology'} differ")
    keys = set(first.arrays)
    for f, d in zip(folders, sets):
        missing = REQUIRED_KEYS - set(d.arrays)
        if missing:
            raise DatasetError(f"{f} lacks the sample arrays {sorted(missing)}; make it again with this version")
        keys &= set(d.arrays)
    # the later sets only train: their held-out bodies (extrapolation) would mix another
    # ground truth into the first set's evaluation splits
    keep = [np.ones(len(first), bool)] + [d.arrays["split"] == "train" for d in sets[1:]]
    arrays = {}
    for k in keys:
        parts = []
        for i, (d, rows) in enumerate(zip(sets, keep)):
            a = d.arrays[k][rows]
            parts.append(a + i * UNIT_STRIDE if k in ("unit", "body") else a)
        arrays[k] = np.concatenate(parts)
    manifest = copy.deepcopy(first.manifest)
    manifest.notes = dict(manifest.notes, merged=[json.loads(d.manifest.to_json()) | {"folder": str(f)}
                                                  for f, d in zip(folders[1:], sets[1:])])
    return DrapeDataset(manifest, arrays, first.faces, first.references)


__all__ = ["make_drape_dataset", "load_drape_dataset", "load_drape_datasets", "DrapeDataset", "Reference"]
