"""`tryon bench perceive`: fabric from video on held-out clips of measured fabrics.

The clips (`tryon dataset clips --presets ...`; made here when none are given) dress
bodies of a seed the training clips do not use in measured fabrics exactly as measured:
the chapter's five lab-measured fabrics by default. For each clip the fabric class is
the classifier's (`--model`, an image-only model of `tryon train fabric-video`) or, with
no classifier, the true class (method `true-class`: what a right classifier gives, so
what the class and the refinement can reach). Then:

- `stiffness_error_pct`: the class's centre against the fabric's stretching stiffness
  (`fabric_classes` axis: warp-weft mean at 16 % strain), relative, in per cent;
  `bending_error_pct` the same for bending;
- `refined_stiffness_error_pct`: after `tryon.perceive.refine_fabric` (the base fabric
  chosen by the clip, then its stretching searched in the class), the simulated garment
  following the clip's first `frames` frames;
- `seconds`: the refinement's wall time per clip on one torch thread.

`top1` / `top3` are the classifier's (null for `true-class`), `chamfer_cm` the per-frame
garment estimator's (null: none yet). One record per clip, then one per method with the
means (`"clip": "mean"`).
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from tryon.bench.records import one_torch_thread, progress_line, write_records
from tryon.errors import TryonError
from tryon.fabric.wang2011 import MEASURED_FABRICS

CHAPTER_FABRICS = ("gray-interlock", "navy-sparkle-sweat", "white-dots-on-blk", "11oz-black-denim", "pink-ribbon-brown")
HELD_OUT_SEED = 1     # the training clips use seed 0: other bodies, motions and cameras
REFINE_FRAMES = 10    # 2 s of the clip at 5 frames a second


def relative_error_pct(estimate_log10: float, truth_log10: float) -> float:
    return float(abs(10.0 ** (estimate_log10 - truth_log10) - 1.0) * 100.0)


def make_bench_clips(folder: Path, presets: tuple[str, ...], per_fabric: int, garment: str = "tshirt") -> Path:
    """The held-out clips (resumed if `folder` holds some of them already)."""
    from tryon.dataset.clips import ClipDatasetSpec, make_clip_dataset

    spec = ClipDatasetSpec(garment=garment, count=len(presets) * per_fabric, presets=presets, seed=HELD_OUT_SEED,
                           shard_size=max(1, len(presets) * per_fabric))
    make_clip_dataset(spec, folder, progress=True)
    return folder


def judge_clip(manifest, folder: Path, sample: dict, classes, model, frames: int, bases: tuple[str, ...],
               grid: int, golden: int | None) -> dict:
    from tryon.dataset.clips import clip_for_refinement
    from tryon.perceive.refine_fabric import refine_clip_fabric

    clip, truth = clip_for_refinement(manifest, folder, sample, frames)
    true_c = classes.class_of(truth)
    s_true, b_true = classes.position(truth)
    rec = {"clip": int(sample["unit"]), "fabric": truth.name, "true_class": classes.name(true_c),
           "top1": None, "top3": None, "chamfer_cm": None}
    c = true_c
    if model is not None:
        from tryon.learn.fabric_from_video import FRAME_KEYS, classify

        p = classify(model, {k: sample[f"frame_{k}"] for k in FRAME_KEYS})
        top = [int(k) for k in np.argsort(-p)[:3]]
        c = top[0]
        rec.update({"top1": float(c == true_c), "top3": float(true_c in top),
                    "within_one_bin": float(classes.distance(c, true_c) <= 1)})
    s_c, b_c = classes.centre(c)
    refined = refine_clip_fabric(clip, classes, c, bases, grid=grid, golden=golden)
    rec.update({"class": classes.name(c), "stiffness_error_pct": relative_error_pct(s_c, s_true),
                "bending_error_pct": relative_error_pct(b_c, b_true),
                "refined_stiffness_error_pct": relative_error_pct(refined.stretch_log10, s_true),
                "refined_base": refined.base, "misfit_at_class_centre": refined.error_centre,
                "misfit_refined": refined.error, "simulations": refined.simulations,
                "seconds": refined.seconds, "frames": frames, "notes": refined.notes})
    return rec


def mean_record(method: str, rows: list[dict]) -> dict:
    def mean(key: str) -> float | None:
        values = [r[key] for r in rows if r.get(key) is not None]
        return float(np.mean(values)) if values else None

    keys = ("top1", "top3", "within_one_bin", "chamfer_cm", "stiffness_error_pct", "bending_error_pct", "refined_stiffness_error_pct",
            "seconds", "misfit_at_class_centre", "misfit_refined")
    out = {"method": method, "clip": "mean", "clips": len(rows), **{k: mean(k) for k in keys}}
    out["refined_better"] = int(sum(r["refined_stiffness_error_pct"] < r["stiffness_error_pct"] for r in rows))
    return out


def run_perceive_bench(json_path: str, clips: str | None = None, model_path: str | None = None,
                       presets: tuple[str, ...] = CHAPTER_FABRICS, per_fabric: int = 2, frames: int = REFINE_FRAMES,
                       bases: tuple[str, ...] = MEASURED_FABRICS, grid: int | None = None, golden: int | None = None,
                       limit: int | None = None) -> list[dict]:
    from tryon.dataset.store import Manifest, ShardStore, sample_rows
    from tryon.perceive.fabric_classes import default_classes
    from tryon.perceive.refine_fabric import GRID_POINTS

    model, method = None, "true-class"
    if model_path:
        from tryon.learn.fabric_from_video import check_image_only
        from tryon.learn.train_fabric_video import load_classifier

        model = load_classifier(model_path)[0]
        check_image_only(model, model_path)
        method = model.method
    made_here = Path(json_path).parent / f"perceive-clips-{len(presets)}x{per_fabric}"  # --quick's apart
    folder = Path(clips) if clips else make_bench_clips(made_here, presets, per_fabric)
    manifest = Manifest.read(folder)
    arrays = ShardStore(folder, manifest).load()
    rows = sample_rows(arrays)[:limit]
    if not len(rows):
        raise TryonError(f"{folder} holds no finished clips to judge")
    classes = default_classes()
    started = time.perf_counter()
    records = []
    with one_torch_thread():
        for i, r in enumerate(rows):
            sample = {k: v[r] for k, v in arrays.items()}
            rec = {"method": method, **judge_clip(manifest, folder, sample, classes, model, frames, bases,
                                                  grid or GRID_POINTS, golden)}
            records.append(rec)
            progress_line("perceive", f"clip {i + 1}/{len(rows)} ({rec['fabric']}): stiffness error "
                          f"{rec['stiffness_error_pct']:.1f} % at the class's centre, "
                          f"{rec['refined_stiffness_error_pct']:.1f} % refined", started)
    records.append(mean_record(method, records))
    write_records(json_path, records, bench="perceive", clips_folder=str(folder), garment=manifest.spec["garment"])
    return records
