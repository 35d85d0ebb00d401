"""A compact copy of a dataset, to keep in version control: garment vertices as float16
(0.5 mm steps at 1 m, well below a drape's noise), everything else as it is, with what
the samples share (a drape dataset's references, a pose dataset's rest drape). The copy
is a dataset of its own: it loads, trains and resumes like the original.

Packing again into the same copy adds only what is new: a file whose samples the copy
already holds is not rewritten (so a copy kept in git grows by the new shards alone),
and samples that have since joined a shard are replaced by it."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np

from tryon.dataset.store import MANIFEST, DatasetError, Manifest, ShardStore
from tryon.io.atomic import atomic_write, claim_work_dir
from tryon.io.npz import read_npz

SAMPLE_FOLDERS = ("shards", "pending")


def pack_dataset(src: str | Path, dst: str | Path, force: bool = False, splits: list[str] | None = None) -> Path:
    """Pack `src` into `dst` (or bring an earlier pack of it up to date). `splits` keeps
    only the samples of those splits (e.g. the held-out bodies a model is judged on,
    shipped with it). Returns the copy's folder."""
    src = Path(src)
    manifest = Manifest.read(src)
    files = _sample_files(src, manifest)
    if not files:
        raise DatasetError(f"{src} holds no samples to pack")
    if splits is not None:
        known = set().union(*(_splits_in(f) for f in files))
        unknown = sorted(set(splits) - known)
        if unknown:
            raise DatasetError(f"{src} has no samples in the split(s) {', '.join(unknown)}; it has {', '.join(sorted(known))}")
    update = _is_pack_of(Path(dst), manifest, splits)
    out = claim_work_dir(dst, resume=update, force=force)
    wanted = {f.relative_to(src) for f in files}
    for old in [p for folder in SAMPLE_FOLDERS for p in (out / folder).glob("*.npz")]:
        if old.relative_to(out) not in wanted:
            old.unlink()  # a sample that has joined a finished shard since the last pack
    for f in files:
        target = out / f.relative_to(src)
        if update and target.exists() and _units(target) == _units(f, splits):
            continue  # the earlier pack of this file holds the same samples
        arrays = _packed(read_npz(f, "dataset file"), splits)
        if arrays is not None:
            target.parent.mkdir(parents=True, exist_ok=True)
            with atomic_write(target, "wb") as fh:
                np.savez_compressed(fh, **arrays)
    _copy_shared(src, out)
    packed = Manifest.read(src)
    packed.notes = dict(packed.notes, packed={"from": str(src), "splits": sorted(splits) if splits else None})
    with atomic_write(out / MANIFEST, "w") as fh:
        fh.write(packed.to_json())
    return out


def _sample_files(src: Path, manifest: Manifest) -> list[Path]:
    store = ShardStore(src, manifest)
    return sorted(store.shards.glob("*.npz")) + (sorted(store.pending.glob("*.npz")) if store.pending.is_dir() else [])


def _is_pack_of(dst: Path, manifest: Manifest, splits: list[str] | None) -> bool:
    """Whether `dst` is an earlier pack of the same data and splits (then it is updated)."""
    if not (dst / MANIFEST).is_file():
        return False
    try:
        there = Manifest.read(dst)
    except DatasetError:
        return False
    packed = there.notes.get("packed")
    return (isinstance(packed, dict) and not there.same_data(manifest)
            and packed.get("splits") == (sorted(splits) if splits else None))


def _units(f: Path, splits: list[str] | None = None) -> list[int]:
    """The units a sample file holds (those of `splits` only, if given), read without
    unpacking its vertices."""
    try:
        with np.load(f) as z:
            units, split = np.atleast_1d(z["unit"]), np.atleast_1d(z["split"]).astype(str)
    except (OSError, ValueError, KeyError) as exc:
        raise DatasetError(f"dataset file {f} cannot be read ({exc}); make it again") from exc
    return units[np.isin(split, splits)].tolist() if splits is not None else units.tolist()


def _splits_in(f: Path) -> set[str]:
    return set(np.atleast_1d(read_npz(f, "dataset file")["split"]).astype(str))


def _packed(arrays: dict[str, np.ndarray], splits: list[str] | None) -> dict | None:
    """One sample file's arrays, vertices in half precision and only the kept splits'
    samples (None when none is kept)."""
    arrays["x"] = arrays["x"].astype(np.float16)
    if splits is None:
        return arrays
    keep = np.isin(np.asarray(arrays["split"]).astype(str), splits)
    if not keep.any():
        return None
    if np.ndim(arrays["split"]) > 0:  # a shard: samples stacked along the first axis
        arrays = {k: v[keep] for k, v in arrays.items()}
    return arrays


def _copy_shared(src: Path, out: Path) -> None:
    """What the samples share: every entry of `src` but the samples, the manifest and the
    folder's own bookkeeping (hidden files)."""
    for shared in sorted(src.iterdir()):
        if shared.name.startswith(".") or shared.name in SAMPLE_FOLDERS or shared.name == MANIFEST:
            continue
        target = out / shared.name
        if shared.is_dir():
            shutil.copytree(shared, target, dirs_exist_ok=True)
        else:
            shutil.copy2(shared, target)


__all__ = ["pack_dataset"]
