"""Fabric presets, loading from names / files / dicts, and saving.

Presets are ARCSim 0.3.1's 12 material files: the 10 fabrics measured by Wang et al.
2011 plus ARCSim's isotropic ``paper`` and ``aluminium`` demo materials.
"""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path
from typing import Any

import torch

from tryon.errors import FabricError
from tryon.fabric.base import Fabric
from tryon.fabric.isotropic import IsotropicFabric
from tryon.fabric.wang2011 import (
    MEASURED_FABRICS,
    MULTIPLIER_KEYS,
    WANG2011_FABRICS,
    WangFabric,
    read_json_with_comments,
)

MEAN_FABRIC_NAME = "wang2011-mean"


def list_presets() -> list[str]:
    """The 10 measured Wang 2011 fabrics followed by ``paper`` and ``aluminium``."""
    return list(WANG2011_FABRICS)


def preset_summaries() -> list[dict]:
    """`Fabric.summary` of every preset, in `list_presets` order."""
    return [WangFabric.from_preset(name).summary() for name in list_presets()]


def mean_preset_fabric() -> WangFabric:
    """Element-wise mean of the 10 measured fabrics' 40 parameters (start point for fabric estimation)."""
    params = torch.stack([WangFabric.from_preset(name).parameters() for name in MEASURED_FABRICS])
    template = WangFabric.from_preset(MEASURED_FABRICS[0])
    mean = template.with_parameters(params.mean(dim=0))
    mean.name = MEAN_FABRIC_NAME
    mean.composition = "element-wise mean of the 10 Wang 2011 measured fabrics"
    mean.multipliers = {}
    return mean


def _multipliers(spec: dict, source: str) -> dict[str, float]:
    return {key: spec[key] for key in MULTIPLIER_KEYS if key in spec}


def _check_keys(spec: dict, allowed: set[str], source: str) -> None:
    unknown = sorted(set(spec) - allowed)
    if unknown:
        raise FabricError(f"{source}: unknown keys {unknown}; allowed keys: {sorted(allowed)}")


def _from_data(data: Any, source: str, default_name: str, multipliers: dict[str, float]) -> Fabric:
    """A fabric from a parsed file or inline dict: isotropic layout or ARCSim's Wang layout."""
    if isinstance(data, dict) and data.get("type") == "isotropic":
        if multipliers:
            raise FabricError(f"{source}: multipliers {sorted(multipliers)} only apply to Wang 2011 fabrics")
        return IsotropicFabric.from_dict(data, source=source)
    if isinstance(data, dict) and data.get("type", "wang2011") != "wang2011":
        raise FabricError(f"{source}: unknown fabric type {data['type']!r}; use 'wang2011' or 'isotropic'")
    name = str(data.get("name", default_name)) if isinstance(data, dict) else default_name
    composition = data.get("composition", WANG2011_FABRICS.get(name, "")) if isinstance(data, dict) else ""
    return WangFabric.from_arcsim_dict(data, name=name, composition=str(composition), source=source, **multipliers)


def _load_path(path: Path, multipliers: dict[str, float]) -> Fabric:
    if not path.is_file():
        raise FabricError(
            f"fabric file {path} does not exist; give a preset name ({', '.join(list_presets())}) or a .json path"
        )
    return _from_data(read_json_with_comments(path), str(path), path.stem, multipliers)


def _load_dict(spec: dict) -> Fabric:
    source = f"fabric spec {spec!r}"
    if "preset" in spec:
        _check_keys(spec, {"preset", *MULTIPLIER_KEYS}, source)
        return WangFabric.from_preset(str(spec["preset"]), **_multipliers(spec, source))
    for key in ("file", "path"):
        if key in spec:
            _check_keys(spec, {key, *MULTIPLIER_KEYS}, source)
            return _load_path(Path(spec[key]), _multipliers(spec, source))
    if spec.get("type") == "isotropic":
        return IsotropicFabric.from_dict(spec, source=source)
    if "stretching" in spec or spec.get("type") == "wang2011":
        _check_keys(spec, {"type", "name", "composition", "density", "stretching", "bending", *MULTIPLIER_KEYS}, source)
        data = {key: value for key, value in spec.items() if key not in MULTIPLIER_KEYS}
        return _from_data(data, source, "wang2011-custom", _multipliers(spec, source))
    raise FabricError(
        f"{source}: give one of {{'preset': name}}, {{'file': path}}, {{'type': 'isotropic', ...}} "
        "or ARCSim data {'density', 'stretching', 'bending'}"
    )


def load_fabric(spec: Any) -> Fabric:
    """A fabric from a preset name, a .json path (either layout), a dict, or a `Fabric` (returned as is).

    Dict forms: ``{"preset": name, "thicken": 2, ...}``, ``{"file": path, ...multipliers}``,
    ``{"type": "isotropic", "youngs_modulus_pa": .., ...}`` or inline ARCSim data.
    """
    if isinstance(spec, Fabric):
        return spec
    if isinstance(spec, dict):
        return _load_dict(spec)
    if isinstance(spec, str) and spec in WANG2011_FABRICS:
        return WangFabric.from_preset(spec)
    if isinstance(spec, (str, os.PathLike)):
        path = Path(spec)
        if path.suffix.lower() == ".json" or path.exists():
            return _load_path(path, {})
        raise FabricError(f"unknown fabric preset {str(spec)!r}; valid presets: {', '.join(list_presets())}")
    raise FabricError(f"cannot make a fabric from {type(spec).__name__}; give a preset name, a .json path or a dict")


def _fabric_to_dict(fabric: Fabric) -> dict:
    if isinstance(fabric, WangFabric):
        return fabric.to_arcsim_dict()
    if isinstance(fabric, IsotropicFabric):
        return fabric.to_dict()
    raise FabricError(f"cannot save fabric of type {type(fabric).__name__}; only WangFabric and IsotropicFabric")


def save_fabric(fabric: Fabric, path: str | os.PathLike) -> None:
    """Write ``fabric`` as JSON (ARCSim layout for Wang fabrics), atomically via a temporary file."""
    path = Path(path)
    text = json.dumps(_fabric_to_dict(fabric), indent=2) + "\n"
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    except OSError as exc:
        raise FabricError(f"cannot write fabric file {path}: {exc}; check the directory is writable") from exc
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as handle:
            handle.write(text)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
