"""`tryon animate DRAPE --motion M --method kdsm [--model MODEL]`: the garment of a drape
through a motion, predicted pose by pose by a trained network (tryon.kdsm) instead of
simulated. Without --model, the hybrid model that ships with tryon (T-shirt M).

The drape must be of the garment and size the model was trained on, on any triangulation
of that pattern and any body: the network's images are read at the drape's material
coordinates. On the model's own body its volume and skinning are used; on another body a
rig is built around that body and its drape, and the network's prediction (d in material
space, or the surface offsets) is applied there (the KDSM paper's transfer to other body
shapes). The body follows the motion as the simulated `tryon animate` poses it (the blend
from the A-pose, then the motion at its own frame rate). Outputs as the simulated
animation's: frames.npz (same `positions` layout), preview.gif, last_frame.png,
metrics.json (penetration per frame) and report.json, with the milliseconds per frame the
prediction took (rendering excluded).
"""

from __future__ import annotations

import time
import warnings
from pathlib import Path

import numpy as np
from tqdm import tqdm

from tryon.errors import TryonError
from tryon.kdsm.model import KdsmModel
from tryon.kdsm.rig import KdsmRig
from tryon.sim.geometry import push_outside

FPS = 30.0
PUSH_GAP = 0.002     # m: predicted vertices nearer the skin than this (or inside) are moved out to it
PUSH_DEPTH = 0.05    # m: deeper than this a vertex is behind an open part of the body, not in it


class DrapePredictor:
    """A trained model set on a drape (its garment, any triangulation, any body), ready to
    give the garment in any pose: what `tryon animate --method kdsm` and live posing share."""

    def __init__(self, drape_dir: str | Path, model_path: str | Path):
        from tryon.body.anny_model import ShapeParams, body_model
        from tryon.drape.animate import load_drape

        self.state = load_drape(drape_dir)
        model = KdsmModel.load(model_path)
        check_garment(model, self.state, model_path)
        self.shape = body_model().rest_shape(ShapeParams.from_dict(self.state["body_params"])).detached()
        tic = time.perf_counter()
        s = self.state
        self.model, self.how = model.on_drape(s["x"], s["faces"], s["corner_uv"], s["face_panel"], self.shape)
        self.rig_s = time.perf_counter() - tic   # building a rig around another body is most of it
        self.net = self.model.build_net() if self.model.method != "skinning" else None

    @property
    def rig(self) -> KdsmRig:
        return self.model.rig

    def garment(self, pose: np.ndarray, translation: np.ndarray | None = None) -> tuple[np.ndarray, float]:
        """The network's garment [n,3] in `pose` (per-bone axis-angle) and the milliseconds it took."""
        tic = time.perf_counter()
        x = self.model.predict(pose, self.net, translation=translation)
        return x, 1000.0 * (time.perf_counter() - tic)

    def body(self, pose: np.ndarray, translation: np.ndarray | None = None) -> np.ndarray:
        return self.rig.body(self.rig.transforms(pose, translation))

    def push_out(self, x: np.ndarray, body: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Vertices the network put inside the body (or nearer it than PUSH_GAP) moved out
        along its normal, as the simulator's contact would keep them; and which moved."""
        x, moved, _ = push_outside(x, body, self.rig.shape.faces, PUSH_GAP, max_depth=PUSH_DEPTH)
        return x, moved


def kdsm_animate(drape_dir: str | Path, model_path: str | Path, motion: str = "walk", out: str | Path | None = None,
                 duration: float | None = None, progress: bool = True, force: bool = False, push_out: bool = True) -> dict:
    """`push_out`: vertices the network put inside the body (or nearer it than PUSH_GAP)
    are moved out along its normal, as the simulator's contact would keep them."""
    from tryon.body.motion import load_motion, motion_poses
    from tryon.body.pose import matrix_to_axis_angle, named_pose
    from tryon.io.atomic import check_output_dir

    t0 = time.perf_counter()
    out = Path(out) if out is not None else Path(drape_dir) / f"animation-{Path(str(motion)).stem}"
    check_output_dir(out, force=force)
    predictor = DrapePredictor(drape_dir, model_path)
    shape, rig = predictor.shape, predictor.rig
    rots, trans, times = motion_poses(shape, load_motion(motion, shape), named_pose(shape, "a"), fps=FPS)
    if duration is not None:
        keep = times <= duration + 1e-9
        rots, trans, times = rots[keep], trans[keep], times[keep]
    positions, bodies, ms, ms_all, inside = [], [], [], [], []
    for R, tr in tqdm(list(zip(rots, trans)), desc="kdsm frames", unit="frame", disable=not progress, leave=False):
        tic = time.perf_counter()
        pose = matrix_to_axis_angle(R)
        x, ms_net = predictor.garment(pose, tr)
        ms.append(ms_net)
        body = predictor.body(pose, tr)
        if push_out:
            x, moved = predictor.push_out(x, body)
            inside.append(100.0 * float(moved.mean()))
        ms_all.append(1000.0 * (time.perf_counter() - tic))
        positions.append(x)
        bodies.append(body)
    report = _write(out, np.stack(positions), np.stack(bodies), times, rig, predictor.state, force)
    how = predictor.how
    report.update({"method": f"kdsm ({predictor.model.method})", "model": str(model_path), "motion": str(motion),
                   "transferred_to_another_body": how == "another body", "mesh": how, "rig_s": predictor.rig_s,
                   "ms_per_frame": float(np.median(ms)), "frames_per_second": 1000.0 / float(np.median(ms)),
                   "ms_per_frame_with_body_and_push_out": float(np.median(ms_all)), "pushed_out": push_out,
                   "pushed_out_vertices_pct_max": max(inside) if inside else None, "wall_s": time.perf_counter() - t0})
    from tryon.io.atomic import atomic_write
    from tryon.io.json_safe import dumps_json

    with atomic_write(out / "report.json") as fh:
        fh.write(dumps_json(report, indent=2))
    return report


def check_garment(model: KdsmModel, state: dict, model_path) -> None:
    """The drape must be of the model's garment and size (any triangulation, any body)."""
    spec = model.card.get("manifest", {}).get("spec", {})
    request = state["request"]
    want = (spec.get("garment"), spec.get("size"))
    got = (request.get("garment"), request.get("size"))
    if None not in want and got != want:
        raise TryonError(f"the model {model_path} is of the {want[0]} {want[1]}; the drape is of the {got[0]} {got[1]}: "
                         f"drape the {want[0]} in size {want[1]}, or train a model on a pose dataset of this garment")
    if spec.get("fabric") and request.get("fabric") != spec["fabric"]:
        warnings.warn(f"the model was trained on {spec['fabric']}; the drape is of {request.get('fabric')}: the "
                      "prediction moves the cloth as the model's fabric", stacklevel=3)


def _write(out: Path, positions: np.ndarray, bodies: np.ndarray, times: np.ndarray, rig: KdsmRig, state: dict,
           force: bool) -> dict:
    from tryon.drape.fit_metrics import penetration
    from tryon.drape.outputs import SKIN
    from tryon.io.atomic import atomic_output_dir, atomic_write
    from tryon.io.frames import save_frames_npz
    from tryon.io.json_safe import dumps_json
    from tryon.render.animation import write_gif
    from tryon.render.appearance import fabric_colors
    from tryon.render.offscreen import Camera, RenderMesh, render_meshes, save_png

    bf = rig.shape.faces
    metrics = [{"time": float(t), **penetration(x, b, bf)} for x, b, t in zip(positions, bodies, times)]
    colors = fabric_colors(str(state["request"]["fabric"]), np.asarray(state["uv"]))
    cam = Camera.fit([np.concatenate([bodies[0], bodies[-1]])], "three_quarter", aspect=0.75, margin=1.15)
    images = [render_meshes([RenderMesh(b, bf, color=SKIN, two_sided=False), RenderMesh(x, rig.faces, vertex_colors=colors)],
                            360, 480, camera=cam) for x, b in zip(positions, bodies)]
    with atomic_output_dir(out, force=force) as tmp:
        save_frames_npz(tmp / "frames.npz", positions, rig.faces, uv=np.asarray(state["uv"]), times=times,
                        body_vertices=bodies, body_faces=bf)
        write_gif(tmp / "preview.gif", images, fps=FPS)
        save_png(tmp / "last_frame.png", images[-1])
        with atomic_write(tmp / "metrics.json") as fh:
            fh.write(dumps_json(metrics, indent=1))
    return {"frames": len(positions), "max_penetration_pct": max(m["penetration_pct"] for m in metrics),
            "mean_penetration_pct": float(np.mean([m["penetration_pct"] for m in metrics]))}
