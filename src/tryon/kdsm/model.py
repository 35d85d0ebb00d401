"""A trained pose-dependent cloth model: the rig (volume, skinning, skin binding, rest
drape), the pixel network and how its inputs and outputs are scaled, in one `.npz` (no
pickle) with its card. `predict(pose)` gives the garment in a pose."""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from tryon.errors import TryonError
from tryon.io.atomic import atomic_write
from tryon.kdsm.network import PanelAtlas, PixelNet
from tryon.kdsm.offsets import SurfaceBinding
from tryon.kdsm.rig import HYBRID_SMOOTHING, METHODS, SMOOTHING_BEFORE_SETTING, KdsmRig
from tryon.kdsm.skinning import VolumeSkin
from tryon.kdsm.volume import TetVolume


def pose_features(pose: np.ndarray, bones: np.ndarray) -> np.ndarray:
    """The network's input: the moving bones' joint rotations (3x3 each, flattened [B*9])
    of a pose given as per-bone axis-angle [J,3]."""
    from tryon.body.pose import axis_angle

    return axis_angle(np.asarray(pose, np.float64)[bones]).reshape(-1)


@dataclass
class KdsmModel:
    method: str
    rig: KdsmRig
    atlas: PanelAtlas
    bones: np.ndarray
    feature_mean: np.ndarray
    feature_std: np.ndarray
    target_mean: np.ndarray
    target_std: np.ndarray
    weights: dict[str, np.ndarray] = field(default_factory=dict)
    card: dict = field(default_factory=dict)

    @property
    def smoothing(self) -> float | None:
        """The hybrid's target smoothing it was trained with (None for other methods)."""
        if self.method != "kdsm-hybrid":
            return None
        if "config" not in self.card:   # saved outside tryon train kdsm (or a best.npz of a run before cards held it)
            return HYBRID_SMOOTHING
        return float(self.card["config"].get("smoothing", SMOOTHING_BEFORE_SETTING))

    def build_net(self) -> PixelNet:
        net = PixelNet(len(self.feature_mean), self.atlas.panels)
        if self.weights:
            net.load_state_dict({k: torch.from_numpy(np.asarray(v, np.float32)) if v.dtype != np.int64 else torch.from_numpy(v)
                                 for k, v in self.weights.items()})
        return net.eval()

    def features(self, pose: np.ndarray) -> np.ndarray:
        return ((pose_features(pose, self.bones) - self.feature_mean) / self.feature_std).astype(np.float32)

    def values(self, net: PixelNet, feats: np.ndarray) -> np.ndarray:
        """Per-vertex values [B,n,3] (the method's target units) for features [B,K]."""
        with torch.no_grad():
            out = self.atlas.sample(net(torch.from_numpy(np.asarray(feats, np.float32))))
        return out.numpy().astype(np.float64) * self.target_std + self.target_mean

    def predict(self, pose: np.ndarray, net: PixelNet | None = None, rig: KdsmRig | None = None,
                translation: np.ndarray | None = None) -> np.ndarray:
        """Garment positions [n,3] in a pose (per-bone axis-angle [J,3], and a root
        translation). `rig`: another body's rig of the same garment (the network's d or
        offsets applied there: transfer to another body shape). Consecutive calls (an
        animation) try each material point's last parent tet first."""
        rig = rig or self.rig
        G = rig.transforms(pose, translation)
        if self.method == "skinning":
            return rig.skinned(G)
        value = self.values(net or self.build_net(), self.features(pose)[None])[0]
        if self.method == "jin-uvn":
            return rig.positions(self.method, value, G)
        from tryon.kdsm.embed import locate_rest

        hint = getattr(self, "_last_tet", None)
        located = locate_rest(rig.x0 + value, rig.volume, hint if hint is not None and getattr(self, "_last_rig", None) is rig else None)
        self._last_tet, self._last_rig = located[0], rig
        return rig.positions(self.method, value, G, located=located)

    def on_drape(self, x: np.ndarray, faces: np.ndarray, corner_uv: np.ndarray, face_panel: np.ndarray,
                 shape) -> tuple["KdsmModel", str]:
        """This model for a drape of its garment (rest positions `x`, any triangulation of
        the pattern) on the body `shape`: (model, how) where how is "own" (the model's rig
        and mesh), "retriangulated" (its body; the images read at the drape's material
        coordinates, the volume and skinning kept) or "another body" (a rig built around
        that body and drape: the KDSM paper's transfer to other body shapes)."""
        from dataclasses import replace

        faces = np.asarray(faces)
        x = np.asarray(x, np.float64)
        same_mesh = faces.shape == self.rig.faces.shape and np.array_equal(faces, self.rig.faces)
        same_body = shape.params.to_dict() == self.rig.shape.params.to_dict()
        if same_mesh and same_body and np.abs(x - self.rig.x0).max() < 1e-3:
            return self, "own"
        atlas = self.atlas if same_mesh else self.atlas.on_garment(faces, corner_uv, face_panel)
        if same_body:
            r = self.rig
            rig = KdsmRig(r.volume, r.skin, SurfaceBinding.bind(x, r.rest_body, r.shape.faces), x, faces, r.shape, r.rest_body)
            how = "retriangulated"
        else:
            rig = KdsmRig.build(x, faces, shape, cell=self.rig.volume.cell)
            how = "another body"
        return replace(self, rig=rig, atlas=atlas), how

    def reset(self) -> None:
        """Forget the last prediction's parent tets (the next pose is not the last one's neighbour)."""
        self._last_tet = self._last_rig = None

    # -- file
    def save(self, path: str | Path) -> Path:
        r = self.rig
        arrays = {"volume_vertices": r.volume.vertices, "volume_tets": r.volume.tets.astype(np.int32),
                  "volume_distance": r.volume.distance.astype(np.float32), "skin_index": r.skin.index.astype(np.int16),
                  "skin_weight": r.skin.weight.astype(np.float32), "skin_rest": r.skin.rest_transforms,
                  "bind_face": r.binding.face, "bind_bary": r.binding.bary, "x0": r.x0, "faces": r.faces,
                  "rest_body": r.rest_body, "atlas_panel": self.atlas.panel, "atlas_coords": self.atlas.coords,
                  **({} if self.atlas.frame is None else {"atlas_frame": self.atlas.frame}),
                  "bones": self.bones, "feature_mean": self.feature_mean, "feature_std": self.feature_std,
                  "target_mean": self.target_mean, "target_std": self.target_std}
        # the large weight tensors as float16 (inference reads them back as float32)
        arrays.update({f"w/{k}": v.astype(np.float16) if v.dtype == np.float32 and v.size > 10_000 else v
                       for k, v in self.weights.items()})
        meta = {"method": self.method, "cell": r.volume.cell, "panels": self.atlas.panels,
                "shape_params": r.shape.params.to_dict(), "card": self.card}
        with atomic_write(path, "wb") as fh:
            np.savez_compressed(fh, meta=json.dumps(meta), **arrays)
        return Path(path)

    @classmethod
    def load(cls, path: str | Path) -> "KdsmModel":
        from tryon.body.anny_model import ShapeParams, body_model

        try:
            d = np.load(path, allow_pickle=False)
            meta = json.loads(str(d["meta"]))
        except (OSError, ValueError, KeyError) as exc:
            raise TryonError(f"{path} is not a KDSM model ({exc}); train one with tryon train kdsm") from None
        if meta.get("method") not in METHODS:
            raise TryonError(f"{path}: unknown method {meta.get('method')!r}")
        shape = body_model().rest_shape(ShapeParams.from_dict(meta["shape_params"])).detached()
        volume = TetVolume(d["volume_vertices"], d["volume_tets"].astype(np.int64), d["volume_distance"].astype(np.float64),
                           float(meta["cell"]))
        weight = d["skin_weight"].astype(np.float64)
        weight /= weight.sum(1, keepdims=True)
        rig = KdsmRig(volume, VolumeSkin(d["skin_index"].astype(np.int64), weight, d["skin_rest"]),
                      SurfaceBinding(d["bind_face"], d["bind_bary"]), d["x0"], d["faces"], shape, d["rest_body"])
        weights = {k[2:]: d[k] for k in d.files if k.startswith("w/")}
        return cls(meta["method"], rig, PanelAtlas(d["atlas_panel"], d["atlas_coords"], int(meta["panels"]),
                                                d["atlas_frame"] if "atlas_frame" in d.files else None), d["bones"],
                   d["feature_mean"], d["feature_std"], d["target_mean"], d["target_std"], weights, meta["card"])


MODELS_DIR = Path(__file__).resolve().parent / "models"
SHIPPED = "tshirt-M-female"   # the garment and body of the shipped models' pose dataset
FROM_REST = "-from-rest"      # the name's ending for a model trained on poses from rest (`--from-rest`)


def shipped_model_path(method: str = "kdsm-hybrid", from_rest: bool = False) -> Path:
    """The model of `method` that ships with tryon (the T-shirt M on the female fit model).
    `from_rest`: the one trained on poses each simulated from the rest drape, whose cloth is
    a function of the pose alone (live posing's default); otherwise the one trained on poses
    carried through sequences, which comes nearer a simulated animation (animation's default)."""
    path = MODELS_DIR / f"{SHIPPED}-{method}{FROM_REST if from_rest else ''}.npz"
    if not path.is_file():
        known = sorted(p.stem for p in MODELS_DIR.glob("*.npz"))
        what = f"{method!r}" + (" trained on poses from rest" if from_rest else "")
        raise TryonError(f"no KDSM model of {what} ships with tryon (shipped: {', '.join(known) or 'none'}); "
                         "train one with tryon train kdsm and pass --model")
    return path


def timed_prediction(model: KdsmModel, poses: np.ndarray, repeats: int = 20) -> float:
    """Median milliseconds to predict the garment in one pose, over consecutive `poses` as
    an animation plays them (network and reconstruction; the KDSM part locates the
    material points, each trying its last parent tet first, and skins only their tets).
    The rest volume's BVH is built before timing."""
    net = model.build_net() if model.method != "skinning" else None
    model.reset()
    model.rig.volume.tree()
    times = []
    for k in range(min(repeats, len(poses))):
        t = time.perf_counter()
        model.predict(poses[k], net)
        times.append(1000.0 * (time.perf_counter() - t))
    return float(np.median(times))

