"""A trained draping model as one file: network weights, the garment hierarchy, the skin
priors of every (gender, size), the body region and normalisation, and the model card.

Stored as a compressed `.npz` (no pickle): `tryon drape --method learned` loads the
shipped T-shirt model from `tryon/learn/models/`."""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from tryon.body.anny_model import ShapeParams
from tryon.drape.dress import DressedGarment
from tryon.errors import TryonError
from tryon.garment.pattern import Pattern
from tryon.io.atomic import atomic_write
from tryon.learn.features import SkinPrior, a_posed_body
from tryon.learn.network import DrapeNet, NetConfig
from tryon.learn.topology import GarmentHierarchy

MODELS_DIR = Path(__file__).parent / "models"
GENDER_CODE = {"male": 0, "female": 1}


class ModelError(TryonError):
    pass


@dataclass
class DrapeModel:
    """Everything needed to predict a drape for a body, gender, size and (a model of many
    fabrics: `config.fabric` > 0) fabric."""

    garment: str
    sizes: list[str]
    config: NetConfig
    hierarchy: GarmentHierarchy
    priors: dict[tuple[str, str], SkinPrior]
    region: np.ndarray          # body vertex ids the encoder reads
    mean_region: np.ndarray     # [M,3] their mean position over the training bodies
    faces: np.ndarray
    garments: dict = field(default_factory=dict)  # (gender, size) -> the reference DressedGarment (rest shape, panels)
    card: dict = field(default_factory=dict)
    fabrics: dict = field(default_factory=dict)  # many fabrics: the features' "mean", "scale", "low", "high", the "names"
    net: DrapeNet | None = None

    def build_net(self) -> DrapeNet:
        if self.net is None:
            self.net = DrapeNet(self.config, self.hierarchy)
        return self.net

    # ------------------------------------------------------------------ inputs
    def body_input(self, body_vertices: np.ndarray) -> np.ndarray:
        """[M,6]: the region's positions and their displacement from the mean body (x10)."""
        r = body_vertices[self.region]
        return np.concatenate([r, 10.0 * (r - self.mean_region)], 1).astype(np.float32)

    def fabric_input(self, features: np.ndarray) -> np.ndarray:
        """[..., F] fabric features (`fabric_features`) normalised as the network reads them."""
        return ((np.asarray(features, np.float64) - self.fabrics["mean"]) / self.fabrics["scale"]).astype(np.float32)

    def fabric_features_of(self, fabric) -> np.ndarray | None:
        """The features of `fabric` (a Fabric) that a model of many fabrics reads; None for a
        model of one fabric. A model of many fabrics refuses to go without one."""
        if not self.config.fabric:
            return None
        if fabric is None:
            raise ModelError(f"the learned {self.garment} model drapes many fabrics: name the fabric")
        from tryon.fabric.blend import fabric_features

        return fabric_features(fabric)

    def trained_fabric(self) -> str | None:
        """The one fabric a model of one fabric was trained in (None for a model of many)."""
        if self.config.fabric:
            return None
        names = self.fabrics.get("names") or [self.card.get("manifest", {}).get("spec", {}).get("fabric")]
        return names[0]

    def size_onehot(self, size: str) -> np.ndarray:
        if size not in self.sizes:
            raise ModelError(f"the learned {self.garment} model knows sizes {', '.join(self.sizes)}, not {size!r}; "
                             "use --method simulate for other sizes")
        v = np.zeros(len(self.sizes), np.float32)
        v[self.sizes.index(size)] = 1.0
        return v

    def reference_garment(self, gender: str, size: str) -> DressedGarment:
        """The size's garment (rest shape, panels) with the reference drape's positions."""
        self.size_onehot(size)
        if (gender, size) not in self.garments:
            raise ModelError(f"the learned {self.garment} model has no {gender} garment in size {size}; use --method simulate")
        return self.garments[(gender, size)]

    def prior(self, gender: str, size: str, body_vertices: np.ndarray) -> np.ndarray:
        if (gender, size) not in self.priors:
            raise ModelError(f"the learned {self.garment} model has no reference for a {gender} body in size {size}; "
                             "use --method simulate")
        return self.priors[(gender, size)].carry(body_vertices)

    def coverage_notes(self, gender: str, height_cm: float, bmi: float, fabric=None) -> list[str]:
        """Where a body (and `fabric`, a Fabric) lies outside what the model was trained on
        (empty when inside)."""
        spec = self.card.get("manifest", {}).get("spec", {})
        r = spec.get("ranges")
        notes = self._fabric_notes(fabric)
        if r and gender not in r["genders"]:
            notes.append(f"the model was trained on {', '.join(r['genders'])} bodies only")
        lo, hi = r["bmi"] if r else (-np.inf, np.inf)
        if not lo <= bmi <= hi:
            notes.append(f"BMI {bmi:.1f} is outside the model's training range {lo:g}-{hi:g}")
        h = r["height_cm"].get(gender) if r else None
        if h and not h[0] <= height_cm <= h[1]:
            notes.append(f"stature {height_cm:.0f} cm is outside the model's training range {h[0]:g}-{h[1]:g} cm")
        return [n + ": refine (--refine) or simulate (--method simulate) to be sure" for n in notes]

    def _fabric_notes(self, fabric) -> list[str]:
        if fabric is None:
            return []
        one = self.trained_fabric()
        if one is not None:
            return [f"the model was trained in {one} only, not {fabric.name}"] if fabric.name != one else []
        from tryon.fabric.blend import FEATURE_NAMES

        f = self.fabric_features_of(fabric)
        low, high = np.asarray(self.fabrics["low"]), np.asarray(self.fabrics["high"])
        outside = [n for n, v, lo, hi in zip(FEATURE_NAMES, f, low, high) if not lo - 1e-6 <= v <= hi + 1e-6]
        return [f"fabric {fabric.name} lies outside the model's training fabrics in {', '.join(outside)}"] if outside else []

    # ------------------------------------------------------------------ prediction
    @torch.no_grad()
    def predict_vertices(self, body_vertices: np.ndarray, gender: str, size: str, fabric=None) -> np.ndarray:
        """The draped garment [N,3] on an A-posed Anny body (vertices [V,3]), in `fabric` (a
        Fabric; a model of one fabric drapes its own whatever is given)."""
        onehot = torch.from_numpy(self.size_onehot(size))[None]
        features = self.fabric_features_of(fabric)
        net = self.build_net().eval()
        body = torch.from_numpy(self.body_input(body_vertices))[None]
        prior = torch.from_numpy(self.prior(gender, size, body_vertices).astype(np.float32))[None]
        fabric_in = None if features is None else torch.from_numpy(self.fabric_input(features))[None]
        out = net(body, torch.tensor([GENDER_CODE[gender]]), onehot, prior, fabric_in)
        return out[0][0].double().numpy()

    def predict(self, params: ShapeParams, gender: str, size: str, fabric=None) -> tuple[np.ndarray, "object"]:
        """(garment vertices, the A-posed body) for Anny shape parameters."""
        body = a_posed_body(params)
        return self.predict_vertices(body.vertices, gender, size, fabric), body

    # ------------------------------------------------------------------ files
    def save(self, path: str | Path) -> Path:
        net = self.build_net()
        arrays = {f"h_{k}": v for k, v in self.hierarchy.to_arrays().items()}
        for (g, s), p in self.priors.items():
            arrays.update(p.to_arrays(f"p_{g}_{s}_"))
        for (g, s), ref in self.garments.items():
            arrays.update({f"g_{g}_{s}_uv": ref.uv, f"g_{g}_{s}_corner_uv": ref.corner_uv, f"g_{g}_{s}_face_panel": ref.face_panel,
                           f"g_{g}_{s}_seam_vertices": ref.seam_vertices,
                           f"g_{g}_{s}_pattern": np.asarray(json.dumps(ref.pattern.to_dict()))})
        for k, v in net.state_dict().items():
            arrays[f"w_{k}"] = v.numpy().astype(np.float16 if v.dtype == torch.float32 and v.numel() > 4096 else v.numpy().dtype)
        meta = {"garment": self.garment, "sizes": self.sizes, "config": self.config.to_dict(), "card": self.card,
                "priors": [list(k) for k in self.priors], "format": 1,
                "fabrics": {k: np.asarray(v).tolist() for k, v in self.fabrics.items()}}
        arrays.update({"region": self.region.astype(np.int32), "mean_region": self.mean_region.astype(np.float32),
                       "faces": self.faces.astype(np.int32), "meta": np.asarray(json.dumps(meta))})
        with atomic_write(path, "wb") as fh:
            np.savez_compressed(fh, **arrays)
        return Path(path)

    @classmethod
    def load(cls, path: str | Path) -> "DrapeModel":
        path = Path(path)
        if not path.is_file():
            raise ModelError(f"no draping model at {path}")
        import zipfile

        try:
            with np.load(path, allow_pickle=False) as z:
                a = {k: z[k] for k in z.files}
            meta = json.loads(str(a["meta"]))
        except (OSError, ValueError, KeyError, zipfile.BadZipFile) as exc:
            raise ModelError(f"{path} is not a tryon draping model ({exc})") from exc
        h = GarmentHierarchy.from_arrays({k[2:]: v for k, v in a.items() if k.startswith("h_")})
        priors = {(g, s): SkinPrior.from_arrays(a, f"p_{g}_{s}_") for g, s in meta["priors"]}
        faces = a["faces"].astype(np.int64)
        garments = {}
        for g, s in meta["priors"]:
            if f"g_{g}_{s}_uv" in a:
                garments[(g, s)] = DressedGarment(priors[(g, s)].x_ref, faces, a[f"g_{g}_{s}_uv"], a[f"g_{g}_{s}_corner_uv"],
                                                  a[f"g_{g}_{s}_face_panel"], Pattern.from_dict(json.loads(str(a[f"g_{g}_{s}_pattern"]))),
                                                  a[f"g_{g}_{s}_seam_vertices"], {"source": f"learned {meta['garment']} {s}"})
        m = cls(meta["garment"], meta["sizes"], NetConfig(**meta["config"]), h, priors, a["region"].astype(np.int64),
                a["mean_region"].astype(np.float64), faces, garments, meta["card"],
                {k: v if k == "names" else np.asarray(v, np.float64) for k, v in meta.get("fabrics", {}).items()})
        if m.config.fabric and "mean" not in m.fabrics:
            raise ModelError(f"{path} reads fabrics but does not say how it normalises them; retrain it")
        net = m.build_net()
        state = {k[2:]: torch.from_numpy(np.asarray(v, np.float32) if v.dtype == np.float16 else v)
                 for k, v in a.items() if k.startswith("w_")}
        try:
            net.load_state_dict(state)
        except RuntimeError as exc:
            raise ModelError(f"{path} does not fit this version of tryon's network ({str(exc)[:200]}); retrain it") from exc
        return m

    def check_dataset(self, spec: dict) -> None:
        """Refuse a dataset whose garment topology or sizes differ from the model's."""
        mine = self.card.get("manifest", {}).get("spec", {})
        for key in ("garment", "edge_length", "topology", "sizes"):
            if key in mine and mine[key] != spec.get(key):
                raise ModelError(f"the dataset's {key} ({spec.get(key)}) differs from the model's ({mine[key]}); "
                                 "judge a model on data of its own garment, sizes and edge length")


def shipped_model_path(garment: str) -> Path:
    return MODELS_DIR / f"{garment}.npz"


def shipped_eval_data_path(garment: str = "tshirt") -> Path:
    """The held-out samples (test and extrapolation splits, `tryon dataset pack --splits`)
    of the data the shipped model was trained on: `tryon bench learned` judges it on them
    by default."""
    path = MODELS_DIR / f"{garment}-eval"
    if not (path / "manifest.json").is_file():
        raise ModelError(f"no held-out drapes ship with the {garment!r} model; give tryon bench learned --data DATASET")
    return path


def load_shipped(garment: str = "tshirt") -> DrapeModel:
    path = shipped_model_path(garment)
    if not path.is_file():
        known = sorted(p.stem for p in MODELS_DIR.glob("*.npz"))
        raise ModelError(f"no learned model for {garment!r} ships with tryon (learned garments: {', '.join(known) or 'none'}); "
                         "use --method simulate")
    return DrapeModel.load(path)


def timestamp() -> str:
    return time.strftime("%Y-%m-%dT%H:%M:%S%z")


__all__ = ["DrapeModel", "ModelError", "load_shipped", "shipped_eval_data_path", "shipped_model_path"]
