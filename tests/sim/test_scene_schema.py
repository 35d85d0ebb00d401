"""The scene schema, the limits and the YAML loader: every case of issue 11 that concerns
scene files gives a one-line TryonError naming the problem, before any work starts."""

import json
import math
import re
from pathlib import Path

import numpy as np
import pytest
import yaml

import tryon.sim.scene as scene_module
from tryon.errors import LimitError, SceneError, TryonError
from tryon.io.json_safe import dumps_json, write_json
from tryon.io.safe_yaml import load_yaml
from tryon.limits import ALLOW_LARGE_ENV, LIMITS, check_limit, large_allowed
from tryon.sim.scene import EXAMPLES, example_spec, load_scene, parse_scene
from tryon.sim.scene_schema import safe_name, scene_format_markdown, validate_scene_spec

DOCS = Path(__file__).resolve().parents[2] / "docs" / "SCENE_FORMAT.md"


def _tiny(**top) -> dict:
    spec = {"cloth": {"grid": {"resolution": 3, "size": [0.2, 0.2]}}, "duration": 0.02}
    spec.update(top)
    return spec


def _refused(spec, match: str, error: type = SceneError) -> str:
    with pytest.raises(error, match=match) as info:
        parse_scene(spec)
    message = str(info.value)
    assert "\n" not in message
    return message


@pytest.mark.parametrize("name", sorted(EXAMPLES))
def test_examples_and_their_dump_load_back(name, tmp_path):
    spec = example_spec(name, 6)
    path = tmp_path / f"{name}.yaml"
    path.write_text(yaml.safe_dump(spec, sort_keys=False))  # what `tryon simulate --example X --dump` prints
    scene = load_scene(path)
    direct = parse_scene(spec)
    assert scene.name == name and scene.num_steps == direct.num_steps
    assert scene.model.num_vertices == 36 and len(scene.model.obstacles.obstacles) == len(spec.get("obstacles", []))
    # the normalised spec the scene keeps parses to the same scene (checkpoint fingerprints, coarsening)
    again = parse_scene(scene.spec)
    assert again.spec == scene.spec and json.dumps(scene.spec)


def test_docstring_example_is_a_valid_scene():
    text = re.search(r"```yaml\n(.*?)```", scene_module.__doc__, re.S).group(1)
    spec = validate_scene_spec(load_yaml(text, "docstring"))
    assert spec.collision.stiffness == 1.0e6 and spec.cloth.handles[0].vertices == [0, 5]
    assert [o.type for o in spec.obstacles] == ["sphere", "box", "plane", "pyramid", "mesh"]


def test_scene_format_doc_is_generated_from_the_schema():
    assert DOCS.read_text() == scene_format_markdown(), \
        "docs/SCENE_FORMAT.md is stale: regenerate it with tryon.sim.scene_schema.scene_format_markdown()"
    for key in ("`stiffness`", "`self_friction`", "`resolution`", "`max_steps`", "N/m per m^2"):
        assert key in DOCS.read_text()


def test_numbers_in_every_yaml_spelling(tmp_path):
    # PyYAML reads 1.0e6 (no exponent sign) as text: it must still reach the solver as a number
    path = tmp_path / "s.yaml"
    path.write_text("cloth: {grid: {resolution: '4', size: [0.2, 2e-1]}}\ndt: 1.0e-2\nduration: '2e-2'\n"
                    "collision: {stiffness: 1.0e6, friction: .3, thickness: 5e-3}\nsolver: {damping: 0}\n")
    scene = load_scene(path)
    c = scene.model.collision
    assert isinstance(c.stiffness, float) and c.stiffness == 1.0e6 and c.friction == 0.3 and c.thickness == 0.005
    assert scene.dt == 0.01 and scene.num_steps == 2 and scene.model.num_vertices == 16


@pytest.mark.parametrize("spec,match", [
    ({"cloth": {"grid": {"resolutoin": 8}}}, r"unknown key 'resolutoin' in 'cloth.grid'; did you mean 'resolution'\?"),
    ({"cloth": {"grid": {}, "fabrc": "paper"}}, r"unknown key 'fabrc' in 'cloth'; did you mean 'fabric'\?"),
    (_tiny(colision={"friction": 0.1}), r"unknown key 'colision'; did you mean 'collision'\?"),
    (_tiny(collision={"friciton": 0.1}), r"did you mean 'friction'\?"),
    (_tiny(obstacles=[{"type": "sphere", "radius": 0.1, "motion": {"velocty": [0, 0, 1]}}]),
     r"'obstacles\[0\].motion'.*did you mean 'velocity'"),
    (_tiny(solver={"damping": float("nan")}), r"'solver.damping' must be a finite number"),
    (_tiny(solver={"damping": ".nan"}), r"'solver.damping' must be a finite number"),
    (_tiny(collision={"friction": -0.2}), r"'collision.friction' must be >= 0"),
    (_tiny(collision={"stiffness": "1.0e6x"}), r"'collision.stiffness' must be a finite number, got '1.0e6x'"),
    (_tiny(collision={"stiffness": 10 ** 400}), r"'collision.stiffness' must be a finite number"),
    (_tiny(collision={"self_collision": "no"}), r"must be true or false"),
    (_tiny(dt=True), r"'dt' must be a number, got True"),
    (_tiny(dt=0.1, frame_time=0.01), r"frame_time \(0.01\) must be at least dt \(0.1\)"),
    (_tiny(gravity=[0, 0]), r"'gravity' must be a list of 3 numbers"),
    (_tiny(name="../../etc/x"), r"'name' must be a simple file name"),
    (_tiny(name="a/b"), r"'name' must be a simple file name"),
    (_tiny(name=".."), r"'name' must be a simple file name"),
    (_tiny(obstacles=[{"type": "plane", "normal": [0, 0, 0]}]), r"'obstacles\[0\].normal' must not be the zero vector"),
    (_tiny(obstacles=[{"type": "sphere", "radius": 0.1, "subdivisions": 12}]), r"'obstacles\[0\].subdivisions' must be <= 6"),
    (_tiny(obstacles=[{"type": "sphere", "radius": 0.1, "motion": {"start": 2, "stop": 1}}]), r"stop \(1.0\) must not be before start"),
    (_tiny(obstacles="sphere"), r"'obstacles' must be a list"),
    (_tiny(solver={"linear": "pgc"}), r"did you mean 'pcg'\?"),
    ({"cloth": {"grid": {}, "pins": ["top-lef"]}}, r"unknown grid corner 'top-lef'.*did you mean 'top-left'"),
    ({"cloth": {"grid": {"resolution": 3}, "pins": [9]}}, r"vertex 9 out of range \[0, 8\]"),
    ({"cloth": {"grid": {"resolution": 3}, "pins": [-1]}}, r"vertex index must be >= 0"),
    ({"cloth": {"grid": {"resolution": 3}, "handles": [{"vertices": []}]}}, r"'cloth.handles\[0\].vertices' must not be empty"),
    ({"cloth": {"grid": {}, "mesh": "a.obj"}}, r"'cloth' needs either 'grid' or 'mesh'"),
    ({"cloth": {"grid": {}, "translate": [0, 0, 1]}}, r"'translate' only applies to a 'mesh' cloth"),
    ({"cloth": {"grid": {}, "fabric": {"preset": "paper", "thicken": "inf"}}}, r"'cloth.fabric.thicken' must be a finite number"),
    ({"cloth": {"grid": {}, "fabric": 7}}, r"'cloth.fabric' must be a preset name"),
    ({"cloth": {"grid": {}, "fabric": {"type": "isotropic", "youngs_modulus_pa": "1e6"}}},
     r"'cloth.fabric' is missing the key 'poisson_ratio'"),
])
def test_bad_values_are_refused_naming_the_key(spec, match):
    _refused(spec, match)


def test_inline_fabric_numbers_are_converted():
    fab = {"type": "isotropic", "youngs_modulus_pa": "1.0e6", "poisson_ratio": 0.3, "thickness_m": "5e-4",
           "bending_stiffness_nm": 1e-6, "density_kg_m2": 0.2}
    scene = parse_scene({"cloth": {"grid": {"resolution": 3}, "fabric": fab}})
    assert math.isclose(float(scene.model.fabric.density), 0.2)


@pytest.mark.parametrize("top,match", [
    ({"duration": 1e4, "dt": 0.001}, r"steps \(duration / dt\): 10,000,000 exceeds the limit max_steps = 200,000"),
    ({"duration": 1e5, "dt": 0.5, "frame_time": 0.5}, r"frames \(duration / frame_time\): 200,002 exceeds the limit max_frames"),
    ({"cloth": {"grid": {"resolution": 50_000}}}, r"cloth.grid.resolution: 50,000 exceeds the limit max_grid_resolution"),
    ({"cloth": {"grid": {"resolution": [1000, 1000]}}}, r"cloth vertices: 1,000,000 exceeds the limit max_vertices = 200,000"),
    ({"cloth": {"grid": {"resolution": [400, 400]}}, "duration": 100, "dt": 0.01, "frame_time": 0.01},
     r"estimated memory \(bytes\).* exceeds the limit max_memory_bytes"),
])
def test_limits_refuse_big_runs_before_any_work(top, match, monkeypatch):
    monkeypatch.delenv(ALLOW_LARGE_ENV, raising=False)
    monkeypatch.setattr(scene_module, "grid_mesh", _must_not_build)
    spec = {"cloth": {"grid": {"resolution": 4}}}
    spec.update(top)
    message = _refused(spec, match, LimitError)
    assert "--allow-large" in message and ALLOW_LARGE_ENV in message


def _must_not_build(*args, **kwargs):
    raise AssertionError("the cloth was built before the limits were checked")


def test_limits_can_be_lifted(monkeypatch):
    spec = _tiny(duration=3000.0, dt=0.01)  # 300 000 steps
    monkeypatch.delenv(ALLOW_LARGE_ENV, raising=False)
    with pytest.raises(LimitError):
        parse_scene(spec)
    assert parse_scene(spec, allow_large=True).num_steps == 300_000
    monkeypatch.setenv(ALLOW_LARGE_ENV, "1")
    assert large_allowed() and parse_scene(spec).num_steps == 300_000
    assert not large_allowed(False)
    with pytest.raises(LimitError, match="cannot be lifted"):
        check_limit("yaml", 10, 5, "max_yaml_aliases", overridable=False)


def test_scene_name_from_a_file_name_is_made_safe(tmp_path):
    path = tmp_path / "my scene..v2.yaml"
    path.write_text(yaml.safe_dump(_tiny()))
    assert load_scene(path).name == "my-scene-v2"
    assert safe_name("../..") == "scene" and safe_name("a/b") == "a-b"


@pytest.mark.parametrize("text,match,error", [
    ("a: &a [1, 2]\n" + "".join(f"l{i}: &l{i} [*{'a' if i == 0 else f'l{i - 1}'}, *{'a' if i == 0 else f'l{i - 1}'}, "
                                 f"*{'a' if i == 0 else f'l{i - 1}'}]\n" for i in range(20)),
     "expands to more than max_yaml_nodes", LimitError),
    ("a: &a [1]\nb: [" + ", ".join(["*a"] * 150) + "]\n", "max_yaml_aliases", LimitError),
    ("a: &a [*a]\n", "refers to itself", SceneError),
    ("[" * 5000 + "]" * 5000, "nested too deeply", SceneError),
    ("cloth: [unclosed\n", "malformed YAML", SceneError),
    ("- 1\n- 2\n", "top level must be a mapping", SceneError),
    ("cloth: {grid: {}}\ndt: 2015-01-01\n", "'dt' must be a number", SceneError),
    ("cloth: !!python/object:os.system {}\n", "malformed YAML", SceneError),
    ("x: 1\n" * 300_000, "max_yaml_bytes", LimitError),
])
def test_hostile_yaml_is_refused(tmp_path, text, match, error):
    path = tmp_path / "s.yaml"
    path.write_text(text)
    with pytest.raises(error, match=match):
        load_scene(path)


def test_json_outputs_never_hold_bare_infinity_or_nan(tmp_path):
    summary = {"min_obstacle_distance": float("inf"), "loss": float("nan"), "x": np.float32(np.inf),
               "arr": np.array([1.0, np.nan]), "ok": 0.5, "path": tmp_path}
    text = dumps_json(summary)
    assert "Infinity" not in text and "NaN" not in text
    back = json.loads(text)
    assert back["min_obstacle_distance"] is None and back["arr"] == [1.0, None] and back["ok"] == 0.5
    out = write_json(tmp_path / "summary.json", summary)
    assert json.loads(out.read_text(), parse_constant=_no_constants)["x"] is None


def _no_constants(name):
    raise AssertionError(f"bare {name} in JSON output")


def test_every_refusal_is_a_tryon_error_not_a_traceback():
    for spec in ([], "cloth", None, {"cloth": None}, {"cloth": {"grid": None}, "obstacles": [None]},
                 {"cloth": {"grid": {"resolution": [2, 2, 2]}}}, {"cloth": {"mesh": 5}}, {"cloth": {"grid": "x"}}):
        with pytest.raises(TryonError):
            parse_scene(spec)
    assert LIMITS.max_steps == 200_000
