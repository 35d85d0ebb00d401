"""Fabric classes: what a clip of a moving garment can tell about its fabric.

After chapter 4 of Liang's dissertation: 6 stretching bins x 9 bending bins = 54 classes
of the Wang 2011 parameter space, the bins "set by how much deformation they produce".
A fabric's place on each axis is its `fabric_features` stiffness (log10 of the warp-weft
mean stretching stiffness at 16 % strain, N/m; log10 of the mean bending stiffness, N m).
The axes span the ten measured fabrics widened by a tenth of their span each side, and
the bin edges sit at equal steps of a standard test's deformation
(`tryon.perceive.fabric_sensitivity`: a hung square for stretching, a drape test for
bending): bins are narrow where a small change of stiffness shows and wide where it no
longer does. The edges and the responses they came from ship in
data/fabric_classes.json; `tryon fabrics --classes --rebuild` measures them again.

Class c is stretching bin c // 9 and bending bin c % 9, both counted from the softest.
A fabric outside the range belongs to the nearest outer bin. `sample_fabric` draws a
fabric inside a class: one of the measured fabrics (its density, anisotropy and
nonlinearity) with its stretching and bending data scaled into the class's box.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path

import numpy as np

from tryon.errors import FabricError
from tryon.fabric.base import Fabric
from tryon.fabric.blend import fabric_features, scaled_stiffness
from tryon.fabric.wang2011 import MEASURED_FABRICS, WangFabric
from tryon.io.json_safe import write_json

CLASSES_FILE = Path(__file__).parent / "data" / "fabric_classes.json"
STRETCH_BINS, BEND_BINS = 6, 9
STRETCH_FEATURE, BEND_FEATURE = 0, 2  # columns of `fabric_features`


@dataclass(frozen=True)
class FabricClasses:
    stretch_edges: tuple[float, ...]  # log10 N/m, softest first
    bend_edges: tuple[float, ...]     # log10 N m, softest first
    provenance: dict = field(default_factory=dict, compare=False, hash=False)

    def __post_init__(self) -> None:
        for name, edges in (("stretch_edges", self.stretch_edges), ("bend_edges", self.bend_edges)):
            if len(edges) < 2 or np.any(np.diff(edges) <= 0):
                raise FabricError(f"fabric classes: {name} must rise and hold at least two edges, got {list(edges)}")

    @property
    def stretch_bins(self) -> int:
        return len(self.stretch_edges) - 1

    @property
    def bend_bins(self) -> int:
        return len(self.bend_edges) - 1

    @property
    def count(self) -> int:
        return self.stretch_bins * self.bend_bins

    def index(self, stretch_bin: int, bend_bin: int) -> int:
        return stretch_bin * self.bend_bins + bend_bin

    def bins(self, c: int) -> tuple[int, int]:
        """(stretching bin, bending bin) of class c."""
        if not 0 <= c < self.count:
            raise FabricError(f"fabric class {c} is outside 0-{self.count - 1}")
        return divmod(int(c), self.bend_bins)

    def name(self, c: int) -> str:
        i, j = self.bins(c)
        return f"S{i + 1}B{j + 1}"

    def position(self, fabric: Fabric) -> tuple[float, float]:
        """(log10 stretching, log10 bending) stiffness: where `fabric` lies on the axes."""
        f = fabric_features(fabric)
        return float(f[STRETCH_FEATURE]), float(f[BEND_FEATURE])

    def inside(self, fabric: Fabric) -> bool:
        s, b = self.position(fabric)
        return (self.stretch_edges[0] <= s <= self.stretch_edges[-1]) and (self.bend_edges[0] <= b <= self.bend_edges[-1])

    def class_of(self, fabric: Fabric) -> int:
        """The class of `fabric` (the nearest outer bin on an axis it lies beyond)."""
        s, b = self.position(fabric)
        return self.index(_bin(self.stretch_edges, s), _bin(self.bend_edges, b))

    def box(self, c: int) -> tuple[tuple[float, float], tuple[float, float]]:
        """((stretch lo, hi), (bend lo, hi)) of class c, log10."""
        i, j = self.bins(c)
        return (self.stretch_edges[i], self.stretch_edges[i + 1]), (self.bend_edges[j], self.bend_edges[j + 1])

    def distance(self, a: int, b: int) -> int:
        """Bins apart on the axis where they are furthest apart (0: same class; 1: neighbours)."""
        (ia, ja), (ib, jb) = self.bins(a), self.bins(b)
        return max(abs(ia - ib), abs(ja - jb))

    def sample_fabric(self, c: int, rng: np.random.Generator, bases: tuple[str, ...] = MEASURED_FABRICS,
                      margin: float = 0.05) -> WangFabric:
        """A fabric of class c: a measured fabric drawn from `bases`, its stretching and
        bending scaled to a point drawn uniformly inside the class's box (kept `margin` of
        the box's width off its edges, so that it is unambiguously of the class)."""
        (s0, s1), (b0, b1) = self.box(c)
        s = rng.uniform(s0 + margin * (s1 - s0), s1 - margin * (s1 - s0))
        b = rng.uniform(b0 + margin * (b1 - b0), b1 - margin * (b1 - b0))
        base_name = str(bases[int(rng.integers(len(bases)))])
        s_base, b_base = self.position(WangFabric.from_preset(base_name))
        fabric = WangFabric.from_preset(base_name, stretching_mult=10.0 ** (s - s_base), bending_mult=10.0 ** (b - b_base))
        fabric.name = f"{base_name}@{self.name(c)}"
        fabric.composition = f"{base_name} scaled into fabric class {self.name(c)}"
        return fabric

    def centre(self, c: int) -> tuple[float, float]:
        """(log10 stretching, log10 bending) at the middle of class c's box."""
        (s0, s1), (b0, b1) = self.box(c)
        return (s0 + s1) / 2, (b0 + b1) / 2

    def nearest_measured(self, c: int, count: int | None = None) -> str | list[str]:
        """The measured fabric nearest the centre of class c (each axis in units of its whole
        range); with `count`, that many, nearest first."""
        spans = np.array([self.stretch_edges[-1] - self.stretch_edges[0], self.bend_edges[-1] - self.bend_edges[0]])
        centre = np.array(self.centre(c))
        away = {n: float(np.linalg.norm((np.array(self.position(WangFabric.from_preset(n))) - centre) / spans))
                for n in MEASURED_FABRICS}
        ranked = sorted(away, key=lambda n: (away[n], n))
        return ranked[0] if count is None else ranked[:count]

    def centre_fabric(self, c: int, base: str | None = None) -> WangFabric:
        """A fabric at the centre of class c: the measured fabric `base` (the nearest one by
        default: its density, anisotropy and non-linearity) with its stiffness scaled there."""
        base = base or self.nearest_measured(c)
        fabric = WangFabric.from_preset(base)
        (s, b), (s_base, b_base) = self.centre(c), self.position(fabric)
        out = scaled_stiffness(fabric, 10.0 ** (s - s_base), 10.0 ** (b - b_base), name=f"{base}@{self.name(c)}")
        out.composition = f"{base} with its stiffness scaled to the centre of fabric class {self.name(c)}"
        return out

    def preset_classes(self) -> dict[str, int]:
        """The class of each measured fabric."""
        return {n: self.class_of(WangFabric.from_preset(n)) for n in MEASURED_FABRICS}

    def to_dict(self) -> dict:
        return {"stretch_edges_log10_N_m": list(self.stretch_edges), "bend_edges_log10_N_m": list(self.bend_edges),
                "provenance": self.provenance}

    @classmethod
    def from_dict(cls, data: dict) -> "FabricClasses":
        try:
            return cls(tuple(map(float, data["stretch_edges_log10_N_m"])), tuple(map(float, data["bend_edges_log10_N_m"])),
                       dict(data.get("provenance", {})))
        except (KeyError, TypeError, ValueError) as exc:
            raise FabricError(f"fabric classes file is malformed ({type(exc).__name__}: {exc})") from None


def _bin(edges: tuple[float, ...], value: float) -> int:
    return int(np.clip(np.searchsorted(edges, value, side="right") - 1, 0, len(edges) - 2))


@lru_cache(maxsize=1)
def default_classes() -> FabricClasses:
    """The shipped classes (data/fabric_classes.json)."""
    if not CLASSES_FILE.is_file():
        raise FabricError(f"{CLASSES_FILE} is missing; run `tryon fabrics --classes --rebuild`")
    return FabricClasses.from_dict(json.loads(CLASSES_FILE.read_text()))


def build_classes(stretch_bins: int = STRETCH_BINS, bend_bins: int = BEND_BINS, samples: int = 13,
                  progress: bool = True) -> FabricClasses:
    """Measure the two tests' responses and place the bin edges at equal deformation steps."""
    from dataclasses import asdict

    from tryon.perceive.fabric_sensitivity import equal_deformation_edges, measure_response

    stretch = measure_response("stretching", samples, progress)
    bend = measure_response("bending", samples, progress)
    provenance = {"method": "equal steps of deformation (tryon.perceive.fabric_sensitivity)",
                  "stretching_test": "1 m square hung from its two top corners, 16 x 16 vertices: hang below "
                                     "its length, mm",
                  "bending_test": "30 cm square on a 16 cm square pedestal, 31 x 31 vertices: 100 (1 - drape "
                                  "coefficient), %",
                  "responses": {"stretching": asdict(stretch), "bending": asdict(bend)}}
    return FabricClasses(tuple(equal_deformation_edges(stretch, stretch_bins)),
                         tuple(equal_deformation_edges(bend, bend_bins)), provenance)


def save_classes(classes: FabricClasses, path: str | Path = CLASSES_FILE) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    write_json(path, classes.to_dict())
    default_classes.cache_clear()
    return path
