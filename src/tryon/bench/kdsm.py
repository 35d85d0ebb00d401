"""`tryon bench kdsm --data POSES --models DIR... --json OUT`: the KDSM paper's tables on a
pose dataset.

- Table 1 (`table: generation`): for each method, the cloth rebuilt from its exact target
  (what a perfect network gives), how far the target moves between consecutive poses and
  how far it spreads over all the poses, on the test sequences (the hybrid's row once for
  each smoothing a benched hybrid was trained with, else at the default; each row says
  which).
- Tables 2 and 3 (`table: learned`): every trained model (`tryon train kdsm`), and
  skinning the rest drape through the volume, on every split: the per-frame mean vertex
  error (cm; mean and spread over frames), the error of the volume the garment encloses
  with its openings capped (cm³; mean and spread) and the milliseconds to predict one
  pose. Every model is judged on the same frames. Each record's `label` is its method, or,
  where two models share a method, the method and the model's folder.

With `--drape DIR` (a drape of the models' garment, any body), also `table:
heldout-motion`: each model's `tryon animate --method kdsm` against the simulated `tryon
animate` of that drape through a motion outside the dataset (`--motion FILE`, default
random key poses from a seed the dataset does not use).

Also writes OUT with .png: the error histograms per model (the paper's Figure 8), the
last pose of the first test sequence with the simulated garment, skinning's and each
model's side by side (`_frames.png`) and, with `--drape`, the simulated garment and each
model's on that drape's body at the held-out motion's most typical frame for the first
model (`_transfer.png`: the paper's transfer to another body shape when the drape's body
is not the dataset's).
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import torch

from tryon.bench.records import write_records
from tryon.errors import TryonError

SPLITS = ("train", "val", "test")


def run_kdsm_bench(json_path: str | Path, data_dir: str | Path, models: list[str | Path], stride: int = 1,
                   progress: bool = True, drape: str | Path | None = None, motion: str | Path | None = None) -> list[dict]:
    from tryon.dataset.poses import load_pose_dataset
    from tryon.kdsm.evaluate import capped_faces, enclosed_volume, generation_table
    from tryon.kdsm.model import KdsmModel, timed_prediction
    from tryon.kdsm.rig import KdsmRig

    t0 = time.perf_counter()
    data = load_pose_dataset(data_dir)
    loaded = [KdsmModel.load(m) for m in models]
    g = data.rest.garment
    for k, (path, m) in enumerate(zip(models, loaded)):
        if m.rig.shape.params.to_dict() != data.rest.params.to_dict():
            raise TryonError(f"the model {path} was not trained on the body of {data_dir}; judge it on its own pose dataset")
        # the dataset may have been made on another triangulation of the pattern (another machine): read the
        # network's images at its material coordinates
        loaded[k] = m.on_drape(g.vertices, g.faces, g.corner_uv, g.face_panel, data.rest.shape())[0]
    rig = loaded[0].rig if loaded else KdsmRig.build(g.vertices, g.faces, data.rest.shape())
    skin_only = KdsmModel("skinning", rig, None, np.zeros(0, np.int64), np.zeros(0), np.ones(0), np.zeros(3), np.ones(3))
    labels = ["skinning"] + model_labels(models, [m.method for m in loaded])
    records = []
    test_rows = data.rows("test")
    if len(test_rows):
        x, poses = data.arrays["x"][test_rows], data.arrays["pose"][test_rows]
        rows = generation_table(rig, x, poses, progress=progress, smoothings=hybrid_smoothings(loaded))
        for r in rows:
            records.append({"table": "generation", "split": "test", "sequences": int(len(test_rows)), **r})
    judged = test_rows if len(test_rows) else data.rows()
    if len(judged):
        records.append(volume_quality_record(rig, data.arrays["pose"][judged][:, ::stride].reshape(
            -1, *data.arrays["pose"].shape[2:]), "test" if len(test_rows) else "all"))
        if progress:
            print(f"kdsm bench: posed volume {records[-1]}", flush=True)
    capped = capped_faces(rig.faces, len(rig.x0))
    per_frame: dict[tuple[str, str], np.ndarray] = {}
    for label, model in zip(labels, [skin_only] + loaded):
        net = model.build_net() if model.method != "skinning" else None
        for split in SPLITS:
            rows = data.rows(split)
            if not len(rows):
                continue
            x = data.arrays["x"][rows][:, ::stride].reshape(-1, *data.arrays["x"].shape[2:]).astype(np.float64)
            poses = data.arrays["pose"][rows][:, ::stride].reshape(-1, *data.arrays["pose"].shape[2:])
            err, verr = [], []
            for xf, pose in zip(x, poses):
                pred = model.predict(pose, net)
                err.append(100.0 * np.linalg.norm(pred - xf, axis=1).mean())
                verr.append(1e6 * abs(enclosed_volume(pred, rig.faces, capped) - enclosed_volume(xf, rig.faces, capped)))
            err, verr = np.asarray(err), np.asarray(verr)
            per_frame[(label, split)] = err
            records += _by_source(model.method, label, split, err,
                                  np.repeat(data.arrays["source"][rows], len(err) // len(rows)))
            records.append({"table": "learned", "method": model.method, "label": label, "split": split, "frames": int(len(err)),
                            "mean_error_cm": float(err.mean()), "std_error_cm": float(err.std()),
                            "volume_error_cm3": float(verr.mean()), "volume_error_std_cm3": float(verr.std()),
                            "inference_ms": timed_prediction(model, poses), "model": model.card.get("trained", "")})
            if progress:
                print(f"kdsm bench: {label} {split}: {err.mean():.3f} +- {err.std():.3f} cm, volume "
                      f"{verr.mean():.0f} cm3 ({time.perf_counter() - t0:.0f} s)", flush=True)
    if drape is not None and loaded:
        work = Path(json_path).parent / "heldout"
        work.mkdir(parents=True, exist_ok=True)
        if motion is None:   # random key poses from a seed no pose dataset uses
            from tryon.body.pose_sampling import random_motion

            motion = work / "random-motion.npz"
            random_motion(data.rest.shape(), seed=data.manifest.seed + 777).save(motion)
        records += heldout_motion_records(models, drape, motion, work, progress, labels=labels[1:],
                                          picture=Path(json_path).with_name(Path(json_path).stem + "_transfer.png"),
                                          from_rest=data.manifest.spec)
    write_records(json_path, records, threads=torch.get_num_threads(), data=str(data_dir))
    _histograms(Path(json_path).with_suffix(".png"), per_frame)
    if len(test_rows):
        _side_by_side(Path(json_path).with_name(Path(json_path).stem + "_frames.png"), data, int(test_rows[0]),
                      dict(zip(labels, [skin_only] + loaded)))
    return records


def hybrid_smoothings(models: list) -> list[float]:
    """The smoothings the benched hybrids were trained with, in order and each once (the
    default when no hybrid is benched): Table 1 shows the hybrid's targets at each."""
    from tryon.kdsm.rig import HYBRID_SMOOTHING

    found = [m.smoothing for m in models if m.method == "kdsm-hybrid"]
    return list(dict.fromkeys(found)) or [HYBRID_SMOOTHING]


def model_labels(paths: list[str | Path], methods: list[str]) -> list[str]:
    """Each model's name in records and pictures: its method, or where two models share a
    method (say, hybrids trained with two smoothings), the method and the model's folder."""
    return [m if methods.count(m) == 1 else f"{m} ({Path(p).parent.name or Path(p).stem})" for p, m in zip(paths, methods)]


def volume_quality_record(rig, poses: np.ndarray, split: str) -> dict:
    """How the skinned volume holds up over poses: inverted tets and the arms' air run into
    the torso's (`tryon.kdsm.quality.pose_quality`), mean and worst pose."""
    from tryon.kdsm.quality import pose_quality, tet_regions

    region = tet_regions(rig.volume, rig.skin, rig.shape)
    q = [pose_quality(rig.volume, rig.skin.pose(rig.volume.vertices, rig.transforms(p)), rig.skin, rig.shape, region)
         for p in poses]
    inv = np.array([r["inverted_pct"] for r in q])
    ovl = np.array([r["arm_torso_overlap_pct"] for r in q])
    return {"table": "volume-quality", "split": split, "poses": int(len(q)), "tets": q[0]["tets"] if q else 0,
            "inverted_pct_mean": float(inv.mean()), "inverted_pct_max": float(inv.max()),
            "arm_torso_overlap_pct_mean": float(ovl.mean()), "arm_torso_overlap_pct_max": float(ovl.max()),
            "poses_with_overlap_pct": float(100.0 * (ovl > 0).mean()),
            "min_volume_ratio": float(min(r["min_volume_ratio"] for r in q))}


def _by_source(method: str, label: str, split: str, err: np.ndarray, source: np.ndarray) -> list[dict]:
    """The per-frame errors of one model and split, apart for each kind of sequence
    (built-in motions, random key poses): the kinds differ by more than the methods."""
    return [{"table": "learned-by-source", "method": method, "label": label, "split": split, "source": str(s),
             "frames": int((source == s).sum()), "mean_error_cm": float(err[source == s].mean()),
             "std_error_cm": float(err[source == s].std())} for s in np.unique(source)]


def heldout_motion_records(models: list[str | Path], drape_dir: str | Path, motion: str | Path, work: Path,
                           progress: bool = True, labels: list[str] | None = None,
                           picture: Path | None = None, from_rest: dict | None = None,
                           from_rest_frames: int = 8) -> list[dict]:
    """Each model's animation of a drape through `motion` against the simulated `tryon
    animate` of the same drape and motion: per-frame mean vertex distance (cm). With
    `picture`, renders the simulated garment and each model's side by side there (titled
    by `labels`, default the models' methods). With `from_rest` (a pose dataset's spec),
    also how far the simulator's own cloth from rest is from the animation: see
    `from_rest_records`."""
    from tryon.drape.animate import animate
    from tryon.kdsm.animate import kdsm_animate

    sim_out = work / "simulated"
    t = time.perf_counter()
    animate(drape_dir, str(motion), out=sim_out, progress=progress, force=True)
    sim_s = time.perf_counter() - t
    sim = np.load(sim_out / "frames.npz")
    records, predicted, errors = [], [], []
    for k, m in enumerate(models):
        out = work / f"model{k}-{Path(m).parent.name or Path(m).stem}"
        rep = kdsm_animate(drape_dir, m, str(motion), out=out, progress=progress, force=True)
        got = np.load(out / "frames.npz")
        pred, times = got["positions"], got["times"]
        keep = times <= sim["times"][-1] + 1e-9
        truth = _at_times(sim["positions"], sim["times"], times[keep])   # the simulated frames at the model's times
        n = int(keep.sum())
        err = 100.0 * np.linalg.norm(pred[keep] - truth, axis=-1).mean(1)
        predicted.append(pred[keep])
        errors.append(err)
        if k == 0:   # every model plays the same motion on the same drape: one body and one truth for the picture
            scene = {"truth": truth, "bodies": got["body_vertices"][keep], "body_faces": got["body_faces"],
                     "faces": got["faces"], "times": times[keep]}
        label = labels[k] if labels else rep["method"]
        records.append({"table": "heldout-motion", "method": rep["method"], "label": label, "split": "heldout-motion",
                        "motion": str(motion),
                        "frames": int(n), "mean_error_cm": float(err.mean()), "std_error_cm": float(err.std()),
                        "max_frame_error_cm": float(err.max()), "inference_ms": rep["ms_per_frame"],
                        "transferred_to_another_body": rep["transferred_to_another_body"], "simulation_s": sim_s})
    if picture is not None and models:
        _heldout_picture(picture, scene, [r["label"] for r in records], predicted, errors)
    if from_rest is not None and models:
        records += from_rest_records(from_rest, drape_dir, motion, scene, predicted, records, from_rest_frames, progress)
    return records


def from_rest_records(spec: dict, drape_dir: str | Path, motion: str | Path, scene: dict, predicted: list[np.ndarray],
                      records: list[dict], count: int = 8, progress: bool = True) -> list[dict]:
    """The dynamics gap of the held-out motion: at `count` frames after the blend, the
    simulator's own cloth for the pose, simulated from the drape at rest as a from-rest
    pose dataset of `spec` records it (with the drape's fabric, thickness and friction),
    against the simulated animation at that frame. It is the error of a model that learned
    the from-rest cloth exactly: the animation carries the cloth with momentum and with
    friction's memory of the path, which the from-rest cloth leaves out (a model trained on
    poses carried through sequences can come nearer); the from-rest run also settles in the
    dataset's still-air damping, the animation has none. Adds to each model's record (in
    `records`) its error at those frames against the animation (`sampled_frames_error_cm`)
    and against the cloth from rest (`from_rest_error_cm`)."""
    from tryon.body.anny_model import ShapeParams, body_model
    from tryon.body.motion import BLEND_TIME, load_motion, motion_poses
    from tryon.body.pose import named_pose
    from tryon.dataset.poses import RestDrape, from_rest_spec, poses_from_rest
    from tryon.drape.animate import load_drape
    from tryon.kdsm.animate import FPS

    t = time.perf_counter()
    state = load_drape(drape_dir)
    request = state["request"]
    shape = body_model().rest_shape(ShapeParams.from_dict(state["body_params"])).detached()
    rots, trans, times = motion_poses(shape, load_motion(str(motion), shape), named_pose(shape, "a"), fps=FPS)
    n = len(scene["times"])
    if not np.allclose(times[:n], scene["times"]):
        raise TryonError("the motion's frames do not match the models' animation")
    after_blend = np.flatnonzero(times[:n] >= times[0] + BLEND_TIME - 1e-9)   # kdsm_animate's blend from the A-pose
    if not len(after_blend):
        return []
    picks = np.unique(np.linspace(after_blend[0], after_blend[-1], count).round().astype(int))
    if progress:
        print(f"kdsm bench: {len(picks)} poses of the held-out motion simulated from rest", flush=True)
    spec = from_rest_spec({**spec, "fabric": request["fabric"],
                           "drape": {**spec["drape"], "thickness": request["thickness"], "friction": request["friction"]}})
    cloth, failed = poses_from_rest(spec, RestDrape.from_drape(state, shape), shape, rots[picks])
    ok = np.isfinite(cloth).all(axis=(1, 2))
    static = cloth[ok] + trans[picks][ok][:, None, :]
    truth = scene["truth"][picks][ok]
    gap = 100.0 * np.linalg.norm(static - truth, axis=-1).mean(1)
    for rec, pred in zip(records, predicted):
        rec["sampled_frames_error_cm"] = _mean_or_none(100.0 * np.linalg.norm(pred[picks][ok] - truth, axis=-1).mean(1))
        rec["from_rest_error_cm"] = _mean_or_none(100.0 * np.linalg.norm(pred[picks][ok] - static, axis=-1).mean(1))
    return [{"table": "heldout-motion", "method": "simulation-from-rest", "label": "simulation from rest",
             "split": "heldout-motion", "motion": str(motion), "frames": int(ok.sum()),
             "frame_times_s": [float(times[f]) for f in picks[ok]],
             "failed_frame_times_s": [float(times[picks[k]]) for k in failed],
             "mean_error_cm": _mean_or_none(gap), "std_error_cm": float(gap.std()) if len(gap) else None,
             "max_frame_error_cm": float(gap.max()) if len(gap) else None,
             "fabric": spec["fabric"], "air_damping": spec["drape"]["air_damping"], "settle_s": spec["settle"],
             "simulation_s": time.perf_counter() - t}]


def _mean_or_none(errors: np.ndarray) -> float | None:
    """The mean, or None where there is nothing (no pose could be simulated from rest)."""
    return float(errors.mean()) if len(errors) else None


def _heldout_picture(path: Path, scene: dict, labels: list[str], predicted: list[np.ndarray],
                     errors: list[np.ndarray]) -> None:
    """The simulated garment and each model's at one frame of the held-out motion: the
    frame whose error for the first model is nearest its mean (typical, not the best)."""
    f = int(np.argmin(np.abs(errors[0] - errors[0].mean())))
    garments = {"simulated": scene["truth"][f]} | {f"{lab} {e[f]:.2f} cm": p[f] for lab, p, e in zip(labels, predicted, errors)}
    _garments_on_body(path, scene["bodies"][f], scene["body_faces"], scene["faces"], garments)


def _at_times(frames: np.ndarray, times: np.ndarray, at: np.ndarray) -> np.ndarray:
    """Frames [T,n,3] at `times` linearly interpolated at the times `at`."""
    k = np.clip(np.searchsorted(times, at, side="right") - 1, 0, len(times) - 2)
    s = np.clip((at - times[k]) / np.maximum(times[k + 1] - times[k], 1e-12), 0.0, 1.0)[:, None, None]
    return (1 - s) * frames[k] + s * frames[k + 1]


def _histograms(path: Path, per_frame: dict) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    tests = {m: e for (m, s), e in per_frame.items() if s == "test"}
    if not tests:
        return
    fig, ax = plt.subplots(figsize=(7, 4))
    top = max(float(e.max()) for e in tests.values())
    bins = np.linspace(0.0, top, 40)
    for m, e in tests.items():
        ax.hist(e, bins=bins, histtype="step", linewidth=1.5, label=f"{m} ({e.mean():.2f} cm)")
    ax.set_xlabel("per-frame mean vertex error (cm), test sequences")
    ax.set_ylabel("frames")
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _side_by_side(path: Path, data, row: int, models: dict) -> None:
    """The last pose of one test sequence: the simulated cloth, then each model's (by label)."""
    rig = next(iter(models.values())).rig
    pose = data.arrays["pose"][row][-1]
    truth = data.arrays["x"][row][-1].astype(np.float64)
    garments = {"simulated": truth}
    for label, m in models.items():
        x = m.predict(pose)
        garments[f"{label} {100 * np.linalg.norm(x - truth, axis=1).mean():.2f} cm"] = x
    _garments_on_body(path, rig.body(rig.transforms(pose)), rig.shape.faces, rig.faces, garments)


def _garments_on_body(path: Path, body: np.ndarray, body_faces: np.ndarray, faces: np.ndarray,
                      garments: dict[str, np.ndarray]) -> None:
    """One tile per garment (titled by its key) on the same body and camera, side by side."""
    from tryon.bench.prints import _titled
    from tryon.drape.outputs import SKIN
    from tryon.render.offscreen import Camera, RenderMesh, render_meshes, save_png

    skin = RenderMesh(body, body_faces, color=SKIN, two_sided=False)
    cam = Camera.fit([body], "three_quarter", aspect=0.75, margin=1.05)
    tiles = [_titled(render_meshes([skin, RenderMesh(x, faces, color=(0.56, 0.57, 0.60))], 360, 480, camera=cam), name)
             for name, x in garments.items()]
    save_png(path, np.concatenate(tiles, axis=1))
