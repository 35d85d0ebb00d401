"""A compact copy of a dataset, to keep in version control: garment vertices as float16
(0.5 mm steps at 1 m, well below a drape's noise), everything else as it is, with what
the samples share (a drape dataset's references, a pose dataset's rest drape). The copy
is a dataset of its own: it loads, trains and resumes like the original.

Packing again into the same copy keeps the files whose samples it already holds
byte for byte (so a copy kept in git grows by the new shards alone). The copy is built
beside the old one and swapped in at the end: a pack that fails leaves the old copy as
it was."""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import numpy as np

from tryon.dataset.drapes import KIND as DRAPE
from tryon.dataset.poses import KIND as POSES
from tryon.dataset.store import MANIFEST, DatasetError, Manifest, ShardStore
from tryon.io.atomic import OWNER_MARKER, atomic_output_dir, atomic_write, is_being_written
from tryon.errors import InputFileError
from tryon.io.npz import read_npz

SHARED = {DRAPE: ("references",), POSES: ("rest.npz", "rest.json")}  # what every sample of a kind shares
PACK_ENTRIES = (MANIFEST, OWNER_MARKER, ".lock", "shards", "pending")


def pack_dataset(src: str | Path, dst: str | Path, force: bool = False, splits: list[str] | None = None) -> Path:
    """Pack `src` into `dst` (or bring an earlier pack of it up to date). `splits` keeps
    only the samples of those splits (e.g. the held-out bodies a model is judged on,
    shipped with it). Returns the copy's folder."""
    src, dst = Path(src), Path(dst)
    manifest = Manifest.read(src)
    splits = sorted(set(splits)) if splits else None
    replaceable = _check_folders(src, dst, manifest, force)
    files = _sample_files(src, manifest)
    if splits is not None:
        known = set().union(*(_splits_in(f) for f in files))
        unknown = sorted(set(splits) - known)
        if unknown:
            raise DatasetError(f"{src} has no samples in the split(s) {', '.join(unknown)}; it has {', '.join(sorted(known))}")
    earlier = dst if replaceable and Manifest.read(dst).notes["packed"].get("splits") == splits else None
    with atomic_output_dir(dst, force=force or replaceable) as out:
        for f in files:
            rel = f.relative_to(src)
            (out / rel).parent.mkdir(parents=True, exist_ok=True)
            if earlier is not None and _same_samples(earlier / rel, f, splits):
                _link(earlier / rel, out / rel)     # the same bytes: git sees no change
                continue
            arrays = _packed(read_npz(f, "dataset file"), splits)
            if arrays is not None:
                with atomic_write(out / rel, "wb") as fh:
                    np.savez_compressed(fh, **arrays)
        if earlier is not None and (earlier / OWNER_MARKER).is_file():
            _link(earlier / OWNER_MARKER, out / OWNER_MARKER, replace=True)
        for name in SHARED[manifest.kind]:
            copy = shutil.copytree if (src / name).is_dir() else shutil.copy2
            copy(src / name, out / name)
        manifest.notes = dict(manifest.notes, packed={"splits": splits})
        with atomic_write(out / MANIFEST, "w") as fh:
            fh.write(manifest.to_json())
    return dst


def _check_folders(src: Path, dst: Path, manifest: Manifest, force: bool) -> bool:
    """Refuse, before any work, a pack that could destroy a dataset or another folder, or
    read a half-written one. Returns whether `dst` is an earlier pack of this very dataset
    holding nothing else (which packing again replaces without --force)."""
    if manifest.kind not in SHARED:
        raise DatasetError(f"{src} holds a {manifest.kind!r} dataset; tryon packs {', '.join(SHARED)} datasets")
    missing = [name for name in SHARED[manifest.kind] if not (src / name).exists()]
    if missing:
        raise DatasetError(f"{src} lacks {', '.join(missing)}; run its generator again (it resumes)")
    a, b = src.resolve(), dst.resolve()
    if a == b or a in b.parents or b in a.parents:
        raise DatasetError(f"the pack of {src} must go to a folder outside it (and not contain it); got --out {dst}")
    for folder in (src, dst):
        if is_being_written(folder):
            raise DatasetError(f"a generator is writing {folder}; pack once that run has stopped")
    if not (dst / MANIFEST).is_file():
        return False
    why = _not_replaceable(dst, manifest)
    if why and not force:
        raise DatasetError(f"{dst} {why}; packing would replace it: choose another --out, or pass --force")
    return not why


def _not_replaceable(dst: Path, manifest: Manifest) -> str | None:
    """Why the dataset folder `dst` is not simply an earlier pack of `manifest`'s dataset."""
    try:
        there = Manifest.read(dst)
    except DatasetError:
        return "holds a damaged dataset manifest"
    if not isinstance(there.notes.get("packed"), dict):
        return "holds a dataset, not a pack of one (a pack made before packs were marked needs --force once)"
    differs = there.same_data(manifest) + (["created"] if there.created != manifest.created else [])
    if differs:
        return f"is a pack of other data (its {', '.join(differs)}: not this dataset's)"
    extra = sorted(p.name for p in dst.iterdir() if p.name not in PACK_ENTRIES + SHARED[manifest.kind])
    if extra:
        return f"holds {', '.join(extra)} besides the pack"
    return None


def _link(a: Path, b: Path, replace: bool = False) -> None:
    """`b` as a hard link to `a` (a copy where the file system has no hard links)."""
    if replace:
        b.unlink(missing_ok=True)
    try:
        os.link(a, b)
    except OSError:
        shutil.copy2(a, b)


def _sample_files(src: Path, manifest: Manifest) -> list[Path]:
    """The sample files of `src`: its shards, then its pending samples (not copies of
    units a shard already holds)."""
    store = ShardStore(src, manifest)
    shards = sorted(store.shards.glob("*.npz")) if store.shards.is_dir() else []
    stranded = set(store.stranded_samples())
    pending = sorted(p for p in store.pending.glob("*.npz") if p not in stranded) if store.pending.is_dir() else []
    files = shards + pending
    if not files:
        raise DatasetError(f"{src} holds no samples to pack")
    return files


def _read_keys(f: Path, keys: tuple[str, ...]) -> dict[str, np.ndarray]:
    """Some arrays of a sample file, without unpacking the others (its vertices)."""
    try:
        return {k: np.atleast_1d(v) for k, v in read_npz(f, "dataset file", allow_large=True, keys=keys).items()}
    except InputFileError as exc:
        raise DatasetError(f"{exc}; make that file again") from exc


def _units(f: Path, splits: list[str] | None = None) -> list[int]:
    """The units a sample file holds (those of `splits` only, if given)."""
    a = _read_keys(f, ("unit", "split"))
    keep = np.isin(a["split"].astype(str), splits) if splits is not None else np.ones(len(a["unit"]), bool)
    return a["unit"][keep].tolist()


def _same_samples(packed: Path, f: Path, splits: list[str] | None) -> bool:
    """Whether the earlier pack's file holds exactly the samples `f` would give it (an
    unreadable one does not: it is written again)."""
    if not packed.is_file():
        return False
    try:
        return _units(packed) == _units(f, splits)
    except DatasetError:
        return False


def _splits_in(f: Path) -> set[str]:
    return set(_read_keys(f, ("split",))["split"].astype(str))


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


__all__ = ["pack_dataset"]
