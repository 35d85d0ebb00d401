"""The scene file format as one typed schema (pydantic): keys, types, units, defaults and
ranges. `validate_scene_spec` turns a parsed YAML mapping into a `SceneSpec` or raises a
one-line `SceneError` naming the key path; `scene_format_markdown` renders the reference
in docs/SCENE_FORMAT.md from the same classes, so the documentation cannot drift.

Numbers are accepted in every YAML spelling: PyYAML reads `1.0e6` (no sign in the
exponent) as text, so numeric text is converted explicitly; NaN and infinities are
refused everywhere. Unknown keys are refused with the nearest valid name.
"""

from __future__ import annotations

import difflib
import math
import re
from typing import Annotated, Any, Literal, Union

from pydantic import BaseModel, BeforeValidator, ConfigDict, Discriminator, Field, StrictBool, Tag, ValidationError, model_validator

from tryon.errors import SceneError

CORNERS = ("bottom-left", "bottom-right", "top-left", "top-right")
OBSTACLE_TYPES = ("sphere", "box", "plane", "pyramid", "mesh")
LINEAR_SOLVERS = ("auto", "pcg-two-level", "pcg", "splu", "cholmod")
NAME_PATTERN = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.+-]{0,99}$")
MAX_GRID_SIDE = 100_000  # hard cap; `tryon.limits` has the (overridable) working limits


# ----------------------------------------------------------------------------- value types

def _show(value: Any, width: int = 60) -> str:
    text = repr(value)
    return text if len(text) <= width else text[: width - 3] + "..."


def to_number(value: Any) -> float:
    """A finite float from an int, a float or numeric text (`1.0e6`, `1e6`, `+.5`)."""
    if isinstance(value, bool) or not isinstance(value, (int, float, str)):
        raise ValueError(f"must be a number, got {_show(value)}")
    if isinstance(value, str):
        text = value.strip()
        if not re.fullmatch(r"[+-]?(\d[\d_]*\.?[\d_]*|\.\d[\d_]*)([eE][+-]?\d+)?", text):
            raise ValueError(f"must be a finite number, got {_show(value)}")
        value = text.replace("_", "")
    try:
        number = float(value)
    except (OverflowError, ValueError):
        raise ValueError(f"must be a finite number, got {_show(value)}") from None
    if not math.isfinite(number):
        raise ValueError(f"must be a finite number, got {_show(value)}")
    return number


def to_int(value: Any) -> int:
    """An int from an int, an integral float or integral numeric text."""
    if isinstance(value, int) and not isinstance(value, bool):
        return value
    number = to_number(value)
    if not number.is_integer():
        raise ValueError(f"must be a whole number, got {_show(value)}")
    return int(number)


def to_text(value: Any) -> str:
    if isinstance(value, bool) or not isinstance(value, (str, int, float)):
        raise ValueError(f"must be text, got {_show(value)}")
    return str(value)


def _vector(n: int, positive: bool = False, nonzero: bool = False):
    def convert(value: Any) -> tuple[float, ...]:
        if not isinstance(value, (list, tuple)) or len(value) != n:
            raise ValueError(f"must be a list of {n} numbers, got {_show(value)}")
        out = tuple(to_number(v) for v in value)
        if positive and min(out) <= 0:
            raise ValueError(f"must be {n} positive numbers, got {_show(value)}")
        if nonzero and not any(out):
            raise ValueError(f"must not be the zero vector, got {_show(value)}")
        return out

    return convert


def _resolution(value: Any) -> tuple[int, int]:
    if not isinstance(value, (list, tuple)):
        value = [value, value]
    if len(value) != 2:
        raise ValueError(f"must be one whole number or a list of 2, got {_show(value)}")
    out = (to_int(value[0]), to_int(value[1]))
    if min(out) < 2 or max(out) > MAX_GRID_SIDE:
        raise ValueError(f"must be between 2 and {MAX_GRID_SIDE} vertices per side, got {_show(value)}")
    return out


def _vertex_ref(value: Any) -> int | str:
    if isinstance(value, str) and not re.fullmatch(r"\s*\d+\s*", value):
        if value in CORNERS:
            return value
        raise ValueError(f"unknown grid corner {value!r}; use one of {list(CORNERS)}{_did_you_mean(value, CORNERS)}")
    index = to_int(value)
    if index < 0:
        raise ValueError(f"vertex index must be >= 0, got {_show(value)}")
    return index


def _vertex_list(value: Any) -> list[int | str]:
    if not isinstance(value, (list, tuple)):
        raise ValueError(f"must be a list of vertex indices or grid corner names, got {_show(value)}")
    return [_vertex_ref(v) for v in value]


def _none_to_empty_list(value: Any) -> Any:
    return [] if value is None else value


def _none_to_empty_dict(value: Any) -> Any:
    return {} if value is None else value


def _scene_name(value: Any) -> str:
    name = to_text(value)
    if not NAME_PATTERN.fullmatch(name) or ".." in name:
        raise ValueError(f"must be a simple file name (letters, digits, '.', '_', '+', '-'; no '/' or '..'), got {_show(value)}")
    return name


def safe_name(name: str) -> str:
    """`name` made into a simple file name (for scene names taken from file names)."""
    cleaned = re.sub(r"[^A-Za-z0-9_.+-]+", "-", name).replace("..", "-").lstrip(".-_+")[:100]
    return cleaned or "scene"


Number = Annotated[float, BeforeValidator(to_number)]
Int = Annotated[int, BeforeValidator(to_int)]
Text = Annotated[str, BeforeValidator(to_text)]
Vec3 = Annotated[tuple[float, float, float], BeforeValidator(_vector(3))]
Direction = Annotated[tuple[float, float, float], BeforeValidator(_vector(3, nonzero=True))]
Size2 = Annotated[tuple[float, float], BeforeValidator(_vector(2, positive=True))]
Size3 = Annotated[tuple[float, float, float], BeforeValidator(_vector(3, positive=True))]
Resolution = Annotated[tuple[int, int], BeforeValidator(_resolution)]
VertexList = Annotated[list[Union[int, str]], BeforeValidator(_vertex_list)]
SceneName = Annotated[str, BeforeValidator(_scene_name)]


def spec_field(default: Any, description: str, unit: str = "", kind: str = "number", limits: str = "",
               **constraints: Any) -> Any:
    """A schema field whose unit, type label and range (`limits` for ranges checked by a
    validator, else the constraints) also go into the generated docs."""
    extra = {"unit": unit, "kind": kind, "range": limits}
    return Field(default, description=description, json_schema_extra=extra, **constraints)


def _did_you_mean(word: str, options: Any) -> str:
    close = difflib.get_close_matches(str(word), [str(o) for o in options], n=1, cutoff=0.5)
    return f"; did you mean {close[0]!r}?" if close else ""


class SpecModel(BaseModel):
    """Base of every scene section: unknown keys are refused naming the nearest valid key."""

    model_config = ConfigDict(extra="forbid", validate_default=False)

    @model_validator(mode="before")
    @classmethod
    def _known_keys(cls, data: Any) -> Any:
        if not isinstance(data, dict):
            raise ValueError(f"must be a mapping (key: value), got {_show(data)}")
        allowed = list(cls.model_fields)
        for key in data:
            if key not in cls.model_fields:
                raise ValueError(f"unknown key {str(key)!r}{_did_you_mean(key, allowed)} (allowed: {', '.join(allowed)})")
        return data


class MotionSpec(SpecModel):
    """Rigid motion of a handle or an obstacle: translation and rotation about a pivot."""

    velocity: Vec3 = spec_field((0.0, 0.0, 0.0), "translation velocity", "m/s", "[x, y, z]")
    angular_velocity_deg: Number = spec_field(0.0, "rotation speed about `axis` through `pivot`", "deg/s", ge=-36_000, le=36_000)
    axis: Direction = spec_field((0.0, 0.0, 1.0), "rotation axis", "", "[x, y, z]", "non-zero")
    pivot: Vec3 = spec_field((0.0, 0.0, 0.0), "point the rotation turns about", "m", "[x, y, z]")
    start: Number = spec_field(0.0, "time the motion starts", "s", ge=0)
    stop: Number | None = spec_field(None, "time the motion stops (default: never)", "s", ge=0)

    @model_validator(mode="after")
    def _window(self) -> "MotionSpec":
        if self.stop is not None and self.stop < self.start:
            raise ValueError(f"stop ({self.stop}) must not be before start ({self.start})")
        return self


class GridSpec(SpecModel):
    """A rectangular cloth generated on a regular grid."""

    resolution: Resolution = spec_field((32, 32), "vertices along u and v (one number: square)", "", "int or [nu, nv]",
        f"2 to {MAX_GRID_SIDE} per side; see max_grid_resolution, max_vertices")
    size: Size2 = spec_field((1.0, 1.0), "side lengths along u and v", "m", "[u, v]", "> 0")
    origin: Vec3 = spec_field((0.0, 0.0, 0.0), "position of the (u, v) = (0, 0) corner", "m", "[x, y, z]")
    orientation: Literal["horizontal", "vertical"] = spec_field(
        "horizontal", "`horizontal`: v along world y; `vertical`: v along world z (hanging)", "", "horizontal | vertical")


class HandleSpec(SpecModel):
    """Pinned vertices that follow a motion from their rest positions."""

    vertices: VertexList = spec_field(..., "vertex indices or grid corner names", "", "list", "at least one", min_length=1)
    motion: MotionSpec | None = spec_field(None, "how the handle moves (default: it stays)", "", "motion")
    stiffness: Number | None = spec_field(
        None, "soft handle: a spring of this stiffness per axis pulls the vertices to the handle, as ARCSim's node "
              "handles (default: held exactly)", "N/m", gt=0, le=1e9)


def _fabric_kind(value: Any) -> str | None:
    if isinstance(value, BaseModel):  # when dumping a validated spec
        return {"FabricPresetSpec": "preset", "FabricFileSpec": "file", "IsotropicFabricSpec": "isotropic"}.get(
            type(value).__name__)
    if isinstance(value, str):
        return "name"
    if not isinstance(value, dict):
        return None
    if "preset" in value:
        return "preset"
    if "file" in value or "path" in value:
        return "file"
    if value.get("type") == "isotropic":
        return "isotropic"
    if "stretching" in value or value.get("type") == "wang2011":
        return "arcsim"
    return None


class _Multipliers(SpecModel):
    density_mult: Number = spec_field(1.0, "areal density multiplier", "", gt=0, le=1000)
    stretching_mult: Number = spec_field(1.0, "stretching stiffness multiplier", "", gt=0, le=1e6)
    bending_mult: Number = spec_field(1.0, "bending stiffness multiplier", "", gt=0, le=1e6)
    thicken: Number = spec_field(1.0, "layers of the fabric stacked (scales density, stretching, bending)", "", gt=0, le=1000)


class FabricPresetSpec(_Multipliers):
    """A measured preset, optionally scaled."""

    preset: Text = spec_field(..., "preset name (`tryon fabrics` lists them)", "", "text")


class FabricFileSpec(_Multipliers):
    """A fabric .json file (ARCSim or isotropic layout), optionally scaled."""

    file: Text | None = spec_field(None, "path of the fabric .json", "", "text")
    path: Text | None = spec_field(None, "same as `file`", "", "text")


class IsotropicFabricSpec(SpecModel):
    """A linear isotropic fabric."""

    type: Literal["isotropic"] = spec_field(..., "`isotropic`", "", "isotropic")
    name: Text = spec_field("isotropic", "fabric name", "", "text")
    composition: Text = spec_field("", "free text", "", "text")
    youngs_modulus_pa: Number = spec_field(..., "Young's modulus", "Pa", gt=0, le=1e13)
    poisson_ratio: Number = spec_field(..., "Poisson's ratio", "", ge=0, lt=0.5)
    thickness_m: Number = spec_field(..., "thickness", "m", gt=0, le=0.1)
    bending_stiffness_nm: Number = spec_field(..., "bending stiffness", "N m", ge=0, le=1e3)
    density_kg_m2: Number = spec_field(..., "areal density", "kg/m^2", gt=0, le=100)


def _arcsim_data(value: Any) -> dict:
    _check_finite(value, "fabric")
    return value


def _check_finite(value: Any, where: str) -> None:
    if isinstance(value, float) and not math.isfinite(value):
        raise ValueError(f"holds a NaN or infinite number at {where}")
    if isinstance(value, dict):
        for k, v in value.items():
            _check_finite(v, f"{where}.{k}")
    elif isinstance(value, (list, tuple)):
        for i, v in enumerate(value):
            _check_finite(v, f"{where}[{i}]")


FabricSpec = Annotated[
    Union[
        Annotated[Text, Tag("name")],
        Annotated[FabricPresetSpec, Tag("preset")],
        Annotated[FabricFileSpec, Tag("file")],
        Annotated[IsotropicFabricSpec, Tag("isotropic")],
        Annotated[dict, BeforeValidator(_arcsim_data), Tag("arcsim")],
    ],
    Discriminator(_fabric_kind, custom_error_type="fabric_form",
                  custom_error_message="must be a preset name, a .json path, {preset: ...}, {file: ...}, "
                                       "{type: isotropic, ...} or ARCSim data {density, stretching, bending}"),
]


class ClothSpec(SpecModel):
    """The cloth: a generated grid or an OBJ mesh, its fabric, pins and handles."""

    grid: Annotated[GridSpec | None, BeforeValidator(_none_to_empty_dict)] = spec_field(
        None, "a generated rectangular cloth (give `grid` or `mesh`)", "", "grid")
    mesh: Text | None = spec_field(None, "OBJ file whose `vt` are material coordinates in metres (relative to the scene file)", "", "path")
    translate: Vec3 | None = spec_field(None, "offset added to the mesh's positions", "m", "[x, y, z]")
    fabric: FabricSpec = spec_field("gray-interlock", "a preset name, a fabric .json, or a mapping", "", "fabric")
    pins: Annotated[VertexList, BeforeValidator(_none_to_empty_list)] = spec_field(
        [], "vertices held in place: indices or grid corner names (top-left, top-right, bottom-left, bottom-right)", "", "list")
    handles: Annotated[list[HandleSpec], BeforeValidator(_none_to_empty_list)] = spec_field(
        [], "pinned vertices that move", "", "list of handle")

    @model_validator(mode="after")
    def _one_shape(self) -> "ClothSpec":
        if (self.grid is None) == (self.mesh is None):
            raise ValueError("needs either 'grid' or 'mesh' (exactly one of them)")
        if self.translate is not None and self.mesh is None:
            raise ValueError("'translate' only applies to a 'mesh' cloth; move a grid with grid.origin")
        return self


class _ObstacleSpec(SpecModel):
    name: SceneName | None = spec_field(None, "obstacle name (default: type and index)", "", "text")
    motion: MotionSpec | None = spec_field(None, "how the obstacle moves (default: static)", "", "motion")


class SphereSpec(_ObstacleSpec):
    """An icosphere."""

    type: Literal["sphere"] = spec_field(..., "`sphere`", "", "sphere")
    center: Vec3 = spec_field((0.0, 0.0, 0.0), "centre", "m", "[x, y, z]")
    radius: Number = spec_field(..., "radius", "m", gt=0, le=1000)
    subdivisions: Int = spec_field(3, "icosphere subdivisions (10 * 4^n + 2 vertices)", "", "int", ge=0, le=6)


class BoxSpec(_ObstacleSpec):
    """An axis-aligned box."""

    type: Literal["box"] = spec_field(..., "`box`", "", "box")
    center: Vec3 = spec_field((0.0, 0.0, 0.0), "centre", "m", "[x, y, z]")
    size: Size3 = spec_field(..., "side lengths", "m", "[x, y, z]", "> 0")


class PlaneSpec(_ObstacleSpec):
    """A square patch of a plane; its normal points to the free side."""

    type: Literal["plane"] = spec_field(..., "`plane`", "", "plane")
    point: Vec3 = spec_field((0.0, 0.0, 0.0), "centre of the patch", "m", "[x, y, z]")
    normal: Direction = spec_field((0.0, 0.0, 1.0), "normal towards the free side", "", "[x, y, z]", "non-zero")
    size: Number = spec_field(4.0, "side length of the patch", "m", gt=0, le=1e4)
    divisions: Int = spec_field(8, "cells along each side", "", "int", ge=1, le=256)


class PyramidSpec(_ObstacleSpec):
    """An open, upside-down square pyramid (a hopper) with its apex at the bottom."""

    type: Literal["pyramid"] = spec_field(..., "`pyramid`", "", "pyramid")
    apex: Vec3 = spec_field((0.0, 0.0, 0.0), "lowest point", "m", "[x, y, z]")
    rim_size: Number = spec_field(..., "side length of the open top", "m", gt=0, le=1000)
    height: Number = spec_field(..., "apex to rim", "m", gt=0, le=1000)


class MeshObstacleSpec(_ObstacleSpec):
    """A triangle mesh file (OBJ, PLY, STL, ...)."""

    type: Literal["mesh"] = spec_field(..., "`mesh`", "", "mesh")
    path: Text = spec_field(..., "mesh file (relative to the scene file)", "", "path")


ObstacleSpec = Annotated[
    Union[SphereSpec, BoxSpec, PlaneSpec, PyramidSpec, MeshObstacleSpec], Field(discriminator="type")]


class WindSpec(SpecModel):
    """Uniform wind acting through ARCSim's face drag model."""

    velocity: Vec3 = spec_field((0.0, 0.0, 0.0), "wind velocity", "m/s", "[x, y, z]")
    density: Number = spec_field(1.0, "air density", "kg/m^3", ge=0, le=100)
    drag: Number = spec_field(0.0, "tangential drag coefficient", "", ge=0, le=100)
    implicit: StrictBool = spec_field(True, "the wind's velocity Jacobian enters the implicit solve; false: an explicit "
                                            "force, as ARCSim adds it", "", "true | false")


class CollisionSpec(SpecModel):
    """Contact parameters."""

    thickness: Number = spec_field(0.005, "distance kept between surfaces", "m", gt=0, le=0.1)
    stiffness: Number = spec_field(1.0e6, "repulsion penalty (ARCSim's collision_stiffness)", "N/m per m^2", gt=0, le=1e12)
    friction: Number = spec_field(0.3, "Coulomb coefficient, cloth against obstacles", "", ge=0, le=10)
    self_friction: Number = spec_field(0.3, "Coulomb coefficient, cloth against cloth", "", ge=0, le=10)
    self_collision: StrictBool = spec_field(True, "resolve cloth-cloth contact", "", "true | false")
    enabled: StrictBool = spec_field(True, "resolve contact at all", "", "true | false")


class SolverSpec(SpecModel):
    """Time integration."""

    linear: Literal["auto", "pcg-two-level", "pcg", "splu", "cholmod"] = spec_field(
        "auto", "linear solver (`auto`: PCG, two-level from 1,500 vertices; `pcg`: block-Jacobi PCG; "
        "`cholmod` needs scikit-sparse)", "", "auto | pcg-two-level | pcg | splu | cholmod")
    damping: Number = spec_field(0.0, "Rayleigh stiffness-proportional damping", "s", ge=0, le=10)
    max_substep_depth: Int = spec_field(3, "a failing step is split in 2, 4, ... 2^depth substeps", "", "int", ge=0, le=10)
    pcg_tol: Number = spec_field(1e-4, "relative residual of the iterative solver", "", gt=0, lt=1)


class SceneSpec(SpecModel):
    """A scene file: the top level."""

    name: SceneName | None = spec_field(None, "scene name, also the default output folder (default: the file name)", "", "text")
    description: Text = spec_field("", "free text", "", "text", max_length=10_000)
    dt: Number = spec_field(0.01, "time step", "s", gt=0, le=1)
    duration: Number = spec_field(1.0, "simulated time", "s", gt=0, le=1e6)
    frame_time: Number | None = spec_field(None, "time between written frames (default: max(dt, 0.04))", "s", "number", ">= dt, <= 1e+06",
        gt=0, le=1e6)
    gravity: Vec3 = spec_field((0.0, 0.0, -9.8), "gravitational acceleration", "m/s^2", "[x, y, z]", "each within +-1000")
    cloth: ClothSpec = spec_field(..., "the cloth", "", "cloth")
    wind: WindSpec | None = spec_field(None, "wind (default: none)", "", "wind")
    obstacles: Annotated[list[ObstacleSpec], BeforeValidator(_none_to_empty_list)] = spec_field(
        [], "collision obstacles", "", "list of obstacle")
    collision: CollisionSpec | None = spec_field(None, "contact settings (default: the defaults below)", "", "collision")
    solver: SolverSpec | None = spec_field(None, "solver settings", "", "solver")

    @model_validator(mode="after")
    def _times(self) -> "SceneSpec":
        if self.frame_time is not None and self.frame_time < self.dt:
            raise ValueError(f"frame_time ({self.frame_time}) must be at least dt ({self.dt})")
        if max(abs(g) for g in self.gravity) > 1000:
            raise ValueError(f"gravity {list(self.gravity)} m/s^2 is implausible (each component at most 1000)")
        return self

    @property
    def effective_frame_time(self) -> float:
        return self.frame_time if self.frame_time is not None else max(self.dt, 0.04)


# ----------------------------------------------------------------------------- errors

def validate_scene_spec(spec: Any, source: str = "scene") -> SceneSpec:
    """`spec` checked against the schema; a `SceneError` naming the first problem otherwise."""
    if not isinstance(spec, dict):
        raise SceneError(f"{source}: the top level must be a mapping with at least a 'cloth' key, got {_show(spec)}")
    if "cloth" not in spec and set(spec) <= set(SceneSpec.model_fields):
        raise SceneError(f"{source}: missing the 'cloth' section (a grid or a mesh plus a fabric)")
    try:
        return SceneSpec.model_validate(spec)
    except ValidationError as exc:
        raise SceneError(f"{source}: {describe_error(exc.errors(include_url=False)[0], spec)}"
                         + _more(exc.error_count())) from None
    except RecursionError:
        raise SceneError(f"{source}: the scene is nested too deeply") from None


def _more(count: int) -> str:
    return f" (and {count - 1} more problem{'s' * (count > 2)})" if count > 1 else ""


_TAGGED = {"obstacles": set(OBSTACLE_TYPES), "fabric": {"name", "preset", "file", "isotropic", "arcsim"}}


def error_path(loc: tuple) -> str:
    """`('cloth', 'handles', 0, 'motion')` -> `cloth.handles[0].motion`, dropping union tags."""
    out = ""
    parts = list(loc)
    for k, part in enumerate(parts):
        if isinstance(part, int):
            out += f"[{part}]"
            continue
        if k >= 1 and part in _TAGGED.get(str(parts[k - 1]), ()) or (
                k >= 2 and isinstance(parts[k - 1], int) and part in _TAGGED.get(str(parts[k - 2]), ())):
            continue
        out += f".{part}" if out else str(part)
    return out


def _field_unit(loc: tuple) -> str:
    """Unit of the field at `loc` ('' when it has none)."""
    model: Any = SceneSpec
    unit = ""
    for part in loc:
        if isinstance(part, int):
            continue
        if model is not None and part in model.model_fields:
            extra = model.model_fields[part].json_schema_extra
            unit = str(extra.get("unit", "")) if isinstance(extra, dict) else ""
            model = _SECTION_MODELS.get(part)
        else:
            model = _TAG_MODELS.get(part)
    return unit


def describe_error(err: dict, spec: Any = None) -> str:
    """One pydantic error as `'path' must be ..., got ...`."""
    loc = tuple(err.get("loc", ()))
    path = error_path(loc)
    kind, ctx, value = err.get("type", ""), err.get("ctx") or {}, err.get("input")
    where = f"'{path}'" if path else "the scene"
    try:
        unit = _field_unit(loc)
    except Exception:  # the unit only decorates the message
        unit = ""
    bounds = {"greater_than": ">", "greater_than_equal": ">=", "less_than": "<", "less_than_equal": "<="}
    if kind in bounds:
        bound = next(iter(ctx.values()))
        if kind == "greater_than" and bound == 0:
            return f"{where} must be a positive number{f' ({unit})' if unit else ''}, got {_show(value)}"
        return f"{where} must be {bounds[kind]} {_num_text(bound)}{f' ({unit})' if unit else ''}, got {_show(value)}"
    if kind == "missing":
        parent = error_path(loc[:-1])
        label = _obstacle_label(loc, spec)
        return f"{repr(parent) if parent else 'the scene'}{label} is missing the key {str(loc[-1])!r}"
    if kind == "union_tag_invalid":
        return (f"{where} has unknown type {ctx.get('tag')!r}; use {', '.join(OBSTACLE_TYPES)}"
                f"{_did_you_mean(ctx.get('tag', ''), OBSTACLE_TYPES)}")
    if kind == "union_tag_not_found":
        return f"{where} needs a 'type' ({', '.join(OBSTACLE_TYPES)})"
    if kind == "literal_error":
        expected = ctx.get("expected", "")
        options = re.findall(r"'([^']*)'", str(expected))
        return f"{where} must be one of {expected}, got {_show(value)}{_did_you_mean(value, options)}"
    if kind == "value_error":
        msg = str(ctx.get("error", err.get("msg", "")))
        if msg.startswith("unknown key ") and path:
            return re.sub(r"^(unknown key '[^']*')", rf"\1 in '{path}'", msg)
        return f"{where} {msg}" if path else msg
    if kind in ("model_type", "model_attributes_type", "dict_type"):
        return f"{where} must be a mapping (key: value), got {_show(value)}"
    if kind == "fabric_form":
        return f"{where} {err.get('msg')}, got {_show(value)}"
    if kind in ("bool_type", "bool_parsing"):
        return f"{where} must be true or false, got {_show(value)}"
    if kind in ("list_type", "tuple_type"):
        return f"{where} must be a list, got {_show(value)}"
    if kind == "string_too_long":
        return f"{where} is too long (at most {ctx.get('max_length')} characters)"
    if kind == "too_short":
        return f"{where} must not be empty"
    return f"{where}: {err.get('msg', 'invalid')}, got {_show(value)}"


def _obstacle_label(loc: tuple, spec: Any) -> str:
    if len(loc) >= 3 and loc[0] == "obstacles" and isinstance(loc[1], int) and isinstance(spec, dict):
        items = spec.get("obstacles")
        if isinstance(items, list) and loc[1] < len(items) and isinstance(items[loc[1]], dict):
            return f" ({items[loc[1]].get('type')})"
    return ""


_SECTION_MODELS: dict[str, Any] = {"cloth": ClothSpec, "grid": GridSpec, "wind": WindSpec, "collision": CollisionSpec,
                                   "solver": SolverSpec, "motion": MotionSpec, "handles": HandleSpec}
_TAG_MODELS: dict[str, Any] = {"sphere": SphereSpec, "box": BoxSpec, "plane": PlaneSpec, "pyramid": PyramidSpec,
                               "mesh": MeshObstacleSpec, "preset": FabricPresetSpec, "file": FabricFileSpec,
                               "isotropic": IsotropicFabricSpec}

# ----------------------------------------------------------------------------- docs

SECTIONS: list[tuple[str, type[SpecModel]]] = [
    ("top level", SceneSpec), ("cloth", ClothSpec), ("cloth.grid", GridSpec), ("cloth.handles[]", HandleSpec),
    ("cloth.fabric: {preset: ...}", FabricPresetSpec), ("cloth.fabric: {file: ...}", FabricFileSpec),
    ("cloth.fabric: {type: isotropic, ...}", IsotropicFabricSpec), ("motion (of a handle or an obstacle)", MotionSpec),
    ("obstacles[]: sphere", SphereSpec), ("obstacles[]: box", BoxSpec), ("obstacles[]: plane", PlaneSpec),
    ("obstacles[]: pyramid", PyramidSpec), ("obstacles[]: mesh", MeshObstacleSpec), ("wind", WindSpec),
    ("collision", CollisionSpec), ("solver", SolverSpec),
]


def _range_text(info: Any) -> str:
    extra = info.json_schema_extra if isinstance(info.json_schema_extra, dict) else {}
    if extra.get("range"):
        return str(extra["range"])
    symbols = {"gt": ">", "ge": ">=", "lt": "<", "le": "<="}
    parts = []
    for meta in info.metadata:
        for attr, sym in symbols.items():
            if getattr(meta, attr, None) is not None:
                parts.append(f"{sym} {_num_text(getattr(meta, attr))}")
    return ", ".join(parts)


def _num_text(value: Any) -> str:
    if isinstance(value, float) and (abs(value) >= 1e5 or 0 < abs(value) < 1e-3):
        return f"{value:g}"
    return str(value)


def _default_text(info: Any) -> str:
    if info.is_required():
        return "required"
    value = info.default
    if value is None:
        return "-"
    if isinstance(value, bool):
        return str(value).lower()
    if isinstance(value, tuple):
        return "[" + ", ".join(_num_text(v) for v in value) + "]"
    if isinstance(value, list):
        return "[]"
    if isinstance(value, str):
        return f"`{value}`" if value else '""'
    return _num_text(value)


def scene_format_markdown() -> str:
    """The scene format reference (docs/SCENE_FORMAT.md), generated from the schema."""
    from tryon.limits import ALLOW_LARGE_ENV, LIMITS

    lines = [
        "# Scene file format",
        "",
        "<!-- generated by tryon.sim.scene_schema.scene_format_markdown(); do not edit by hand. -->",
        "",
        "A scene is a YAML mapping; every key but `cloth` is optional. Unknown keys are refused",
        "with the nearest valid name; numbers may be written in any YAML spelling (`1.0e6`, `1e6`,",
        "`1000000`) but NaN and infinities are refused. Paths are relative to the scene file.",
        "",
    ]
    for title, model in SECTIONS:
        lines += [f"## {title}", "", (model.__doc__ or "").strip().splitlines()[0], "",
                  "| key | type | unit | default | range | meaning |", "|---|---|---|---|---|---|"]
        for key, info in model.model_fields.items():
            extra = info.json_schema_extra if isinstance(info.json_schema_extra, dict) else {}
            cells = [f"`{key}`", str(extra.get("kind", "")), str(extra.get("unit", "")), _default_text(info),
                     _range_text(info), info.description or ""]
            lines.append("| " + " | ".join(c.replace("|", "\\|") for c in cells) + " |")
        lines.append("")
    lines += [
        "## Limits", "",
        "Checked before any work starts. The overridable ones are lifted by `--allow-large`,",
        f"`allow_large=True` in Python or the environment variable `{ALLOW_LARGE_ENV}=1`.", "",
        "| limit | value | overridable |", "|---|---|---|",
    ]
    fixed = {"max_yaml_bytes", "max_yaml_aliases", "max_yaml_nodes"}
    for key, value in vars(LIMITS).items():
        lines.append(f"| `{key}` | {value:,} | {'no' if key in fixed else 'yes'} |")
    return "\n".join(lines) + "\n"
