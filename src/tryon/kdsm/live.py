"""Live posing: the garment of a drape in whatever pose the viewer's sliders set, predicted
by a trained network as they move (`tryon view DRAPE --live`).

The sliders are the joint angles the pose datasets draw from (`pose_sampling.LIMITS`:
each arm's elevation, azimuth and elbow, each leg's hip flexion, abduction and knee, the
spine's bend, side bend and twist), over the ranges the network was trained on. A pose is one forward pass
and one reconstruction (docs/KDSM.md gives the milliseconds measured), the body skinned
to it, vertices the network put inside the body pushed out as `tryon animate --method
kdsm` does.
"""

from __future__ import annotations

import threading
from pathlib import Path

import numpy as np

from tryon.errors import TryonError

START = {"arm_elevation.L": 45.0, "arm_elevation.R": 45.0}   # near the drape's A-pose; the rest straight


def live_controls() -> list[dict]:
    """The sliders: name, label, range (degrees) and starting value."""
    from tryon.body.pose_sampling import LIMITS, angle_names, default_angle

    out = []
    for name in angle_names():
        key, _, side = name.partition(".")
        lo, hi = LIMITS[key]
        label = key.replace("_", " ") + {"L": " (left)", "R": " (right)", "": ""}[side]
        out.append({"name": name, "label": label, "min": lo, "max": hi, "value": START.get(name, default_angle(name))})
    return out


def live_angles(values: dict[str, float]) -> dict[str, float]:
    """Every slider's angle: `values` (checked: known names, finite, within the trained
    range) and the others at their start."""
    known = {c["name"]: c for c in live_controls()}
    unknown = sorted(set(values) - set(known))
    if unknown:
        raise TryonError(f"unknown joint angle(s) {', '.join(unknown)}; the angles are {', '.join(known)}")
    for name, v in values.items():
        lo, hi = known[name]["min"], known[name]["max"]
        if not (np.isfinite(v) and lo <= v <= hi):
            raise TryonError(f"{name} = {v} is outside the range the model was trained on ({lo:g} to {hi:g} degrees)")
    return {**{c["name"]: c["value"] for c in known.values()}, **values}


class LivePoser:
    """A drape and a trained model, ready to give the garment in any pose of the sliders."""

    def __init__(self, drape_dir: str | Path, model_path: str | Path):
        from tryon.kdsm.animate import DrapePredictor

        self.predictor = DrapePredictor(drape_dir, model_path)
        self.shape = self.predictor.shape
        state = self.predictor.state
        self.faces, self.corner_uv = np.asarray(state["faces"]), np.asarray(state["corner_uv"])
        model = self.predictor.model
        self.method = model.method + (" on another body" if self.predictor.how == "another body" else "")
        self._lock = threading.Lock()   # the server answers requests in threads; the network runs one at a time

    def controls(self) -> list[dict]:
        return live_controls()

    def angles(self, values: dict[str, float]) -> dict[str, float]:
        return live_angles(values)

    def frame(self, values: dict[str, float]) -> dict[str, np.ndarray | float]:
        """The garment [n,3] and body [m,3] in the pose of `values` (degrees by slider
        name; the others at their start), the garment's per-vertex strain in % and the
        milliseconds the prediction took."""
        from tryon.body.pose import matrix_to_axis_angle
        from tryon.body.pose_sampling import pose_from_angles
        from tryon.viewer.export import vertex_strain_percent

        pose = matrix_to_axis_angle(pose_from_angles(self.shape, self.angles(values)))
        with self._lock:
            x, ms = self.predictor.garment(pose)
            body = self.predictor.body(pose)
        x, _ = self.predictor.push_out(x, body)
        strain = vertex_strain_percent(x[None], self.faces, self.corner_uv)[0]
        return {"garment": x, "body": body, "strain": strain, "ms": ms}


__all__ = ["LivePoser", "START", "live_angles", "live_controls"]
