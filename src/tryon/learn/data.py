"""Training tensors from a drape dataset (`tryon.dataset`), cached next to the model.

Per sample: the target body's region vertices and normals, the skinned prior, the true
drape, the truth's candidate closest body vertices (for the c/d split of the loss), and
the features of the drape's fabric."""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree
from tqdm import tqdm

from tryon.body.anny_model import ShapeParams, body_model
from tryon.dataset.drapes import shape_params
from tryon.dataset.loading import DrapeDataset
from tryon.learn.features import SkinPrior, a_posed_body, body_region
from tryon.sim.geometry import area_vertex_normals
from tryon.learn.topology import build_hierarchy

CANDIDATES = 8
CACHE_VERSION = 3  # 2: the fabric's features; 3: its name
GENDERS = ("male", "female")


@dataclass
class TrainingSet:
    rows: np.ndarray        # dataset row of each sample
    split: np.ndarray       # [S] str
    gender: np.ndarray      # [S] 0 male, 1 female
    size: np.ndarray        # [S] index into the dataset's sizes
    shape: np.ndarray       # [S,P] Anny shape vectors
    fabric: np.ndarray      # [S,F] `fabric_features` of each drape's fabric
    fabric_name: np.ndarray  # [S] str, its name (`tryon.dataset.drapes.recorded_fabric_names`)
    body: np.ndarray        # [S,M,3] region vertices
    normals: np.ndarray     # [S,M,3]
    prior: np.ndarray       # [S,N,3]
    truth: np.ndarray       # [S,N,3]
    cand: np.ndarray        # [S,N,K] candidate closest region vertices of the truth

    def subset(self, keep: np.ndarray) -> "TrainingSet":
        return TrainingSet(*(getattr(self, f)[keep] for f in self.__dataclass_fields__))


def references(data: DrapeDataset, folder: Path) -> dict[tuple[str, str], tuple[np.ndarray, object]]:
    """(reference drape, fit-model body) per (gender, size) of the dataset."""
    known = json.loads((folder / "references" / "references.json").read_text())
    out = {}
    for (g, s), garment in data.references.items():
        out[(g, s)] = (garment.vertices, a_posed_body(ShapeParams.from_dict(known[f"{g}-{s}"]["params"])))
    return out


def model_parts(data: DrapeDataset, folder: Path, levels: int = 4, eigen: int = 128):
    """The hierarchy, skin priors and body region of a dataset's garment."""
    refs = references(data, folder)
    topo = data.manifest.spec["topology"]
    key = (topo["gender"], topo["size"])
    # the topology's own reference is the hierarchy's source; any reference has the same faces
    base = data.references.get(key) or next(iter(data.references.values()))
    hierarchy = build_hierarchy(base.faces, base.corner_uv, base.face_panel, base.pattern, data.manifest.spec["edge_length"],
                                levels=levels, eigenvectors=eigen)
    priors = {k: SkinPrior.bind(x, body.vertices, body.faces) for k, (x, body) in refs.items()}
    region = body_region([(x, body.vertices) for x, body in refs.values()])
    return hierarchy, priors, region


def dataset_key(data: DrapeDataset) -> str:
    units = np.sort(data.arrays["unit"])
    h = hashlib.sha1(units.tobytes() + json.dumps(data.manifest.spec, sort_keys=True).encode())
    merged = data.manifest.notes.get("merged")
    if merged:  # sets trained on together: which ones, not only how many samples
        h.update(json.dumps([[m["seed"], m["count"], m["spec"]] for m in merged], sort_keys=True).encode())
    return h.hexdigest()[:12]


def training_set(data: DrapeDataset, priors: dict, region: np.ndarray, cache: Path | None = None,
                 progress: bool = True) -> TrainingSet:
    """Every good sample of the dataset as arrays (cached in `cache` by the dataset's content)."""
    if cache is not None:
        path = cache / f"features-{CACHE_VERSION}-{dataset_key(data)}.npz"
        if path.exists():
            with np.load(path, allow_pickle=False) as z:
                return TrainingSet(**{k: z[k] for k in z.files})
    a = data.arrays
    rows = data.rows()
    sizes = data.manifest.spec["sizes"]
    faces = body_model().rest_shape(ShapeParams()).faces
    cols: dict[str, list] = {k: [] for k in ("body", "normals", "prior", "truth", "cand")}
    for r in tqdm(rows, desc="preparing samples", unit="sample", disable=not progress):
        gender = GENDERS[int(a["gender"][r])]
        body = a_posed_body(shape_params(a["shape_params"][r])).vertices
        normals = area_vertex_normals(body, faces)[region]
        truth = a["x"][r].astype(np.float64)
        _, cand = cKDTree(body[region]).query(truth, k=CANDIDATES)
        cols["body"].append(body[region].astype(np.float32))
        cols["normals"].append(normals.astype(np.float32))
        cols["prior"].append(priors[(gender, sizes[int(a["size"][r])])].carry(body).astype(np.float32))
        cols["truth"].append(truth.astype(np.float32))
        cols["cand"].append(cand.astype(np.int32))
    ts = TrainingSet(rows, a["split"][rows].astype(str), a["gender"][rows].astype(np.int64), a["size"][rows].astype(np.int64),
                     a["shape_params"][rows].astype(np.float32), a["fabric_features"][rows].astype(np.float32),
                     a["fabric_name"][rows].astype(str),
                     *(np.stack(cols[k]) for k in cols))
    if cache is not None:
        cache.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(".tmp.npz")
        np.savez(tmp, **{f: getattr(ts, f) for f in ts.__dataclass_fields__})
        tmp.replace(path)
    return ts
