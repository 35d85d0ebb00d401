"""Fuzzing every input reader: random and mutated scene mappings, scene YAML text, BVH text,
motion and observation npz files and OBJ text. Each case must end, within a time limit, in
a valid result or a one-line `TryonError` - never another exception, a hang, or a file
written outside the test's folder. Plus the issue's own cases as explicit regressions."""

from __future__ import annotations

import contextlib
import copy
import signal
from pathlib import Path

import numpy as np
import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from tryon.body.bvh import joint_world, load_bvh, parse_bvh
from tryon.body.motion import BodyMotion, load_motion
from tryon.diff.observed import Observation, load_observed, save_observed
from tryon.errors import InputFileError, LimitError, MeshError, TryonError
from tryon.io.mesh_io import read_obj
from tryon.sim.integrator import ImplicitEulerSolver
from tryon.sim.mesh import grid_mesh, mesh_from_obj
from tryon.sim.scene import EXAMPLES, example_spec, load_scene, parse_scene

CASE_SECONDS = 5.0  # per fuzz case; the issue asks for an answer "within a few seconds"
FUZZ = settings(derandomize=True, deadline=None, database=None, max_examples=150,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])


class CaseTimeout(BaseException):
    """Raised by the alarm; a BaseException so that no `except Exception` in the code swallows it."""


@contextlib.contextmanager
def time_limit(seconds: float = CASE_SECONDS):
    def expire(signum, frame):
        raise CaseTimeout(f"a case took longer than {seconds} s")

    previous = signal.signal(signal.SIGALRM, expire)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)


def outcome(fn, *args, **kwargs):
    """`fn(...)` under the time limit: its result, or the TryonError it raised (one line)."""
    with time_limit():
        try:
            return fn(*args, **kwargs)
        except TryonError as exc:
            assert "\n" not in str(exc) and str(exc), f"error message is not one line: {exc!r}"
            return exc


@pytest.fixture(scope="module")
def warm_solver():
    """One step before any timed case: the first step compiles the numba kernels."""
    scene = parse_scene({"cloth": {"grid": {"resolution": 3}}, "obstacles": [{"type": "sphere", "radius": 0.1,
                                                                               "center": [0, 0, -0.2]}]})
    ImplicitEulerSolver(scene.model, scene.options).step(scene.model.initial_state(), scene.dt)


@pytest.fixture
def sandbox(tmp_path, monkeypatch, warm_solver):
    """A working directory whose content is checked after the test: nothing may appear
    outside it, and nothing but what the test itself wrote inside it."""
    monkeypatch.chdir(tmp_path)
    monkeypatch.delenv("TRYON_ALLOW_LARGE", raising=False)
    repo = Path(__file__).resolve().parents[2]
    before = _listing(repo)
    yield tmp_path
    assert _listing(repo) == before, "a fuzz case wrote files into the repository"


def _listing(root: Path) -> set[str]:
    return {str(p.relative_to(root)) for p in root.rglob("*") if ".git" not in p.parts and "__pycache__" not in p.parts
            and ".pytest_cache" not in p.parts and ".hypothesis" not in p.parts and ".cache" not in p.parts}


# ----------------------------------------------------------------------------- values

ODD_NUMBERS = [0, -1, 1, 2, 3, 0.5, -0.5, 1e-7, 1e-300, 1e6, 1e300, 2 ** 63, -(2 ** 63), 10 ** 400, float("nan"),
               float("inf"), -float("inf"), 1.0e6, 32.5]
ODD_TEXT = ["1.0e6", "1e6", "nan", ".inf", "-.inf", "", " ", "abc", "../..", "/etc/passwd", "top-left", "sphere", "1_000",
            "0x10", "\x00", "é", "paper", "gray-interlock", "1e999", "-0", "..", "a/b"]
leaf = st.one_of(st.sampled_from(ODD_NUMBERS), st.sampled_from(ODD_TEXT), st.booleans(), st.none(),
                 st.integers(-5, 40), st.floats(allow_nan=True, allow_infinity=True), st.text(max_size=6))
json_like = st.recursive(leaf, lambda kids: st.one_of(st.lists(kids, max_size=4),
                                                      st.dictionaries(st.text(max_size=8), kids, max_size=4)),
                         max_leaves=12)


def _paths(value, prefix=()):
    """Every (path, value) inside a nested mapping/list."""
    yield prefix, value
    if isinstance(value, dict):
        for k, v in value.items():
            yield from _paths(v, prefix + (k,))
    elif isinstance(value, list):
        for i, v in enumerate(value):
            yield from _paths(v, prefix + (i,))


def _set(root, path, value):
    node = root
    for part in path[:-1]:
        node = node[part]
    node[path[-1]] = value


@st.composite
def mutated_scene(draw):
    spec = example_spec(draw(st.sampled_from(sorted(EXAMPLES))), draw(st.integers(2, 5)))
    for _ in range(draw(st.integers(1, 3))):
        paths = [p for p, _ in _paths(spec) if p]
        path = draw(st.sampled_from(paths))
        action = draw(st.sampled_from(["replace", "delete", "unknown", "rename"]))
        parent = spec
        for part in path[:-1]:
            parent = parent[part]
        if action == "replace":
            _set(spec, path, draw(json_like))
        elif action == "delete" and isinstance(parent, dict):
            del parent[path[-1]]
        elif action == "unknown" and isinstance(parent, dict):
            parent[draw(st.text(min_size=1, max_size=8))] = draw(json_like)
        elif action == "rename" and isinstance(parent, dict) and isinstance(path[-1], str):
            parent[path[-1][:-1] + "x"] = parent.pop(path[-1])
    return spec


def _try_scene(scene_or_error, tmp: Path):
    if isinstance(scene_or_error, TryonError):
        return
    scene = scene_or_error
    out_root = (tmp / "out").resolve()
    assert (out_root / scene.name).resolve().parent == out_root, f"scene name {scene.name!r} leaves the output folder"
    small = scene.model.num_vertices <= 64 and len(scene.model.obstacles.faces) <= 5000
    if small:  # one step of a tiny valid scene: a TryonError (e.g. SimulationError) or a finite state
        def step():
            state, _ = ImplicitEulerSolver(scene.model, scene.options).step(scene.model.initial_state(), scene.dt)
            return state

        state = outcome(step)
        if not isinstance(state, TryonError):
            assert np.isfinite(state.x.numpy()).all()


# ----------------------------------------------------------------------------- scenes

@FUZZ
@given(spec=mutated_scene())
def test_fuzz_mutated_scene_mappings(spec, sandbox):
    _try_scene(outcome(parse_scene, copy.deepcopy(spec)), sandbox)


@FUZZ
@given(spec=st.one_of(json_like, st.dictionaries(st.sampled_from(["cloth", "dt", "duration", "frame_time", "name",
                                                                  "obstacles", "collision", "solver", "wind", "gravity"]),
                                                 json_like, max_size=6)))
def test_fuzz_random_scene_mappings(spec, sandbox):
    _try_scene(outcome(parse_scene, spec), sandbox)


@FUZZ
@given(spec=mutated_scene(), cut=st.one_of(st.none(), st.integers(0, 2000)),
       junk=st.one_of(st.none(), st.binary(max_size=12), st.sampled_from([b"&a", b"*a", b": ", b"- ", b"{", b"!!str "])),
       at=st.integers(0, 2000))
def test_fuzz_scene_yaml_text(spec, cut, junk, at, sandbox):
    text = yaml.safe_dump(spec, sort_keys=False, allow_unicode=True).encode()
    if junk is not None:
        text = text[:at] + junk + text[at:]
    if cut is not None:
        text = text[: max(cut, len(text) // 2)]
    path = sandbox / "scene.yaml"
    path.write_bytes(text)
    _try_scene(outcome(load_scene, path), sandbox)


# ----------------------------------------------------------------------------- BVH

BVH = """HIERARCHY
ROOT Hips
{
  OFFSET 0 0 0
  CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation
  JOINT Spine
  {
    OFFSET 0 10 0
    CHANNELS 3 Zrotation Xrotation Yrotation
    End Site
    {
      OFFSET 0 10 0
    }
  }
  JOINT LeftUpLeg
  {
    OFFSET 8 -2 0
    CHANNELS 3 Zrotation Xrotation Yrotation
    End Site
    {
      OFFSET 0 -40 0
    }
  }
}
MOTION
Frames: 2
Frame Time: 0.033333
0 90 0 0 0 0 5 0 0 0 0 0
1 90 0 10 0 0 5 0 0 10 0 0
"""
BVH_TOKENS = ["0", "1", "2", "0.5", "-3", "-1", "0", "7", "1000000000000", "1e6", "1e-7", "nan", "inf", "{", "}", "ROOT", "JOINT", "End",
              "Site", "CHANNELS", "OFFSET", "MOTION", "Frames:", "Frame", "Time:", "Xrotation", "Qrotation", "x"]


@FUZZ
@given(edits=st.lists(st.tuples(st.integers(0, 200), st.sampled_from(["replace", "delete", "insert"]),
                                st.sampled_from(BVH_TOKENS)), min_size=1, max_size=4),
       cut=st.one_of(st.none(), st.integers(0, 400)))
def test_fuzz_bvh_text(edits, cut, sandbox):
    tokens = BVH.split(" ")
    for pos, action, token in edits:
        pos %= len(tokens)
        if action == "replace":
            tokens[pos] = token
        elif action == "delete":
            del tokens[pos]
        else:
            tokens.insert(pos, token)
    text = " ".join(tokens)
    if cut is not None:
        text = text[: max(cut, len(text) - 40)]
    bvh = outcome(parse_bvh, text, "fuzz.bvh")
    if not isinstance(bvh, TryonError):
        world, root = outcome(joint_world, bvh)
        assert np.isfinite(world).all() and np.isfinite(root).all()


def test_bvh_regressions():
    """The issue's BVH cases: a negative CHANNELS count looped forever; absurd frame times
    started millions of frames."""
    assert parse_bvh(BVH, "ok.bvh").values.shape == (2, 12)
    cases = [
        (BVH.replace("CHANNELS 3 Zrotation Xrotation Yrotation\n    End Site\n    {\n      OFFSET 0 10 0",
                     "CHANNELS -3 Zrotation Xrotation Yrotation\n    End Site\n    {\n      OFFSET 0 10 0"), "0 to 6 CHANNELS"),
        (BVH.replace("CHANNELS 3", "CHANNELS 300000", 1), "0 to 6 CHANNELS"),
        (BVH.replace("Frame Time: 0.033333", "Frame Time: 1e-7"), r"Frame Time must lie in \[0.001, 1.0\] s"),
        (BVH.replace("Frame Time: 0.033333", "Frame Time: 1e6"), r"Frame Time must lie in"),
        (BVH.replace("Frame Time: 0.033333", "Frame Time: nan"), r"must be finite"),
        (BVH.replace("Frames: 2", "Frames: 100000000"), r"frames: 100,000,000 exceeds the limit max_frames"),
        (BVH.replace("Frames: 2", "Frames: 3"), r"expected 3 frames of 12 channel values, found 24"),
        (BVH.replace("Frames: 2", "Frames: -2"), r"Frames must be at least 1"),
        (BVH[: BVH.index("MOTION")], r"no MOTION section"),
        (BVH[: BVH.index("JOINT LeftUpLeg")], r"no MOTION section"),
        (BVH.replace("Xrotation", "Qrotation", 1), r"unknown channel 'Qrotation'"),
        (BVH.replace("0 90 0 0 0 0 5", "0 90 0 0 0 0 inf"), r"NaN or infinite"),
        (BVH.replace("ROOT Hips\n{", "ROOT Hips\n{\n{"), r"'\{' without a ROOT"),
        ("HIERARCHY\n" + "JOINT a { " * 5, r"JOINT in the wrong place"),
    ]
    for text, match in cases:
        with time_limit(2.0), pytest.raises(TryonError, match=match):
            parse_bvh(text, "case.bvh")


def test_bvh_file_limits(tmp_path, monkeypatch):
    path = tmp_path / "big.bvh"
    path.write_text(BVH)
    monkeypatch.setattr("tryon.limits.LIMITS", _limits(max_file_bytes=100))
    with pytest.raises(LimitError, match="max_file_bytes"):
        load_bvh(path)
    assert load_bvh(path, allow_large=True).values.shape == (2, 12)


def _limits(**changes):
    import dataclasses

    from tryon.limits import LIMITS

    return dataclasses.replace(LIMITS, **changes)


# ----------------------------------------------------------------------------- motion npz

def _save_npz(path: Path, arrays: dict) -> Path:
    with open(path, "wb") as fh:
        np.savez(fh, **arrays)
    return path


def _valid_motion() -> dict:
    return {"rotations": np.zeros((4, 2, 3)), "bone_labels": np.array(["root", "head"]), "fps": np.float64(30.0),
            "root_translation": np.zeros((4, 3)), "name": np.array("wave")}


ODD_ARRAYS = st.sampled_from([np.zeros(0), np.zeros((4, 2, 3)), np.zeros((4, 3)), np.full((4, 2, 3), np.nan),
                              np.array(1e-6), np.array(1e7), np.array(np.inf), np.array(30), np.array("30"),
                              np.array(["root", "head"]), np.array([b"root", b"head"]), np.array([True]),
                              np.zeros((2, 2, 2, 2)), np.array(-1), np.arange(6).reshape(2, 3), np.array([1 + 2j]),
                              np.zeros((100_000, 2, 3), np.float32)])


@FUZZ
@given(changes=st.dictionaries(st.sampled_from(["rotations", "bone_labels", "fps", "root_translation", "name", "extra"]),
                               st.one_of(st.none(), ODD_ARRAYS), max_size=3),
       corrupt=st.one_of(st.none(), st.none(), st.none(), st.tuples(st.integers(0, 4000), st.binary(min_size=1, max_size=8))))
def test_fuzz_motion_npz(changes, corrupt, sandbox):
    arrays = _valid_motion()
    for key, value in changes.items():
        if value is None:
            arrays.pop(key, None)
        else:
            arrays[key] = value
    path = _save_npz(sandbox / "m.npz", arrays)
    if corrupt is not None:
        data = bytearray(path.read_bytes())
        at = corrupt[0] % len(data)
        data[at:at + len(corrupt[1])] = corrupt[1]
        path.write_bytes(bytes(data))
    motion = outcome(load_motion, path)
    if not isinstance(motion, TryonError):
        assert isinstance(motion, BodyMotion) and 1 <= motion.fps <= 1000 and np.isfinite(motion.rotations).all()


def test_motion_regressions(tmp_path):
    """fps 1e-6 made a 1e8-step animation, fps 1e7 millions of skinned frames."""
    for fps, match in ((1e-6, r"'fps' must lie in \[1, 1000\]"), (1e7, r"'fps' must lie in"), (np.nan, "'fps' must lie in")):
        arrays = _valid_motion()
        arrays["fps"] = np.float64(fps)
        with pytest.raises(InputFileError, match=match):
            load_motion(_save_npz(tmp_path / "m.npz", arrays))
    with pytest.raises(TryonError, match=r"fps must lie in \[1, 1000\]"):
        BodyMotion(np.zeros((2, 1, 3)), ["root"], 1e-6)
    arrays = _valid_motion()
    arrays["rotations"] = np.zeros((4, 3, 3))
    with pytest.raises(InputFileError, match=r"'rotations' must be \[\*, 2, 3\] numbers"):
        load_motion(_save_npz(tmp_path / "m.npz", arrays))
    (tmp_path / "pickle.npz").write_bytes(b"\x80\x04K\x01.")
    with pytest.raises(InputFileError, match="not a readable .npz"):
        load_motion(tmp_path / "pickle.npz")
    objects = _save_npz(tmp_path / "obj.npz", dict(_valid_motion(), name=np.array([{"a": 1}], dtype=object)))
    with pytest.raises(InputFileError, match="holds Python objects"):
        load_motion(objects)


# ----------------------------------------------------------------------------- observation npz

def _valid_observation() -> dict:
    m = grid_mesh((3, 3), (0.2, 0.2))
    x = m.x.numpy()
    return {"positions": np.stack([x, x, x + 0.001]), "faces": m.faces.numpy(), "uv": m.uv.numpy(),
            "pinned": np.array([6, 8]), "frame_time": np.float64(0.04), "gravity": np.array([0, 0, -9.8]),
            "wind_velocity": np.zeros(3), "wind_density": np.float64(1.0), "wind_drag": np.float64(0.0),
            "dt": np.float64(0.01), "fabric": np.array("paper")}


OBS_KEYS = list(_valid_observation())
ODD_OBS = st.sampled_from([np.zeros(0), np.array(1e6), np.array(1e-7), np.array(np.nan), np.array(-1.0),
                           np.array([[0, 1, 99]]), np.array([[0, 1, -5]]), np.array([[0.0, 1.0, 2.0]]),
                           np.zeros((3, 9, 3)), np.full((3, 9, 3), np.inf), np.zeros((9, 2)), np.zeros((1, 9, 3)),
                           np.array([100]), np.array("x"), np.zeros(3), np.array([0.0, 0.0, 1e9]), np.array(True)])


@FUZZ
@given(changes=st.dictionaries(st.sampled_from(OBS_KEYS), st.one_of(ODD_OBS, ODD_OBS, ODD_OBS, st.none()), max_size=2))
def test_fuzz_observation_npz(changes, sandbox):
    arrays = _valid_observation()
    for key, value in changes.items():
        if value is None:
            arrays.pop(key, None)
        else:
            arrays[key] = value
    obs = outcome(load_observed, _save_npz(sandbox / "o.npz", arrays))
    if not isinstance(obs, TryonError):
        assert isinstance(obs, Observation)
        from tryon.fabric import load_fabric

        outcome(obs.model, load_fabric("paper"))  # a valid model or a MeshError naming the problem


def test_observation_regressions(tmp_path):
    """frame_time 1e6 started 1e8 solver steps per frame; 1e-7 an absurd step."""
    cases = [("frame_time", np.float64(1e6), r"'frame_time' must lie in \[0.001, 10\] s"),
             ("frame_time", np.float64(1e-7), r"'frame_time' must lie in"),
             ("dt", np.float64(1e-9), r"'dt' must lie in"),
             ("faces", np.array([[0, 1, 9]]), r"'faces' indices must lie in \[0, 8\]"),
             ("positions", np.full((3, 9, 3), np.nan), r"'positions' contains NaN"),
             ("pinned", np.array([0.5]), r"'pinned' must hold integer indices"),
             ("gravity", np.array([0, 0, -1e9]), r"'gravity' components must lie within")]
    for key, value, match in cases:
        arrays = _valid_observation()
        arrays[key] = value
        with pytest.raises(InputFileError, match=match):
            load_observed(_save_npz(tmp_path / "o.npz", arrays))
    arrays = _valid_observation()
    arrays["positions"] = np.zeros((30_000, 9, 3))
    arrays["dt"] = np.float64(0.001)
    with pytest.raises(LimitError, match="max_frames"):
        load_observed(_save_npz(tmp_path / "o.npz", arrays))
    obs = load_observed(_save_npz(tmp_path / "o.npz", _valid_observation()))
    save_observed(tmp_path / "again.npz", obs)
    assert load_observed(tmp_path / "again.npz").steps_per_frame == 4


# ----------------------------------------------------------------------------- OBJ

OBJ = """v 0 0 0
v 0.1 0 0
v 0 0.1 0
v 0.1 0.1 0
vt 0 0
vt 0.1 0
vt 0 0.1
vt 0.1 0.1
f 1/1 2/2 4/4
f 1/1 4/4 3/3
"""
OBJ_LINES = ["v nan 0 0", "v 1e400 0 0", "vt 1 1", "f 1/1 2/2 9/9", "f 0 1 2", "f -1/-1 -2/-2 -3/-3", "f 1 2",
             "f 1/1 1/1 1/1", "v 0 0", "f a b c", "vt", "vt inf 0", "f 1//1 2//2 3//3", "mtllib x.mtl", "g x"]


@FUZZ
@given(edits=st.lists(st.tuples(st.integers(0, 20), st.sampled_from(["replace", "delete", "insert"]),
                                st.sampled_from(OBJ_LINES)), max_size=3), scale=st.sampled_from([1.0, 10.0, 0.01]))
def test_fuzz_obj_text(edits, scale, sandbox):
    lines = OBJ.splitlines()
    lines = [f"vt {float(ln.split()[1]) * scale} {float(ln.split()[2]) * scale}" if ln.startswith("vt ") else ln
             for ln in lines]
    for pos, action, line in edits:
        pos %= len(lines)
        if action == "replace":
            lines[pos] = line
        elif action == "delete" and len(lines) > 1:
            del lines[pos]
        else:
            lines.insert(pos, line)
    path = sandbox / "cloth.obj"
    path.write_text("\n".join(lines) + "\n")
    outcome(read_obj, path)
    mesh = outcome(mesh_from_obj, path)
    if not isinstance(mesh, TryonError):
        assert np.isfinite(mesh.x.numpy()).all()


def test_texture_coordinates_in_0_1_on_a_small_mesh_are_refused(tmp_path):
    """0-1 vt on a 10 cm mesh ran at -90 % strain without a word."""
    path = tmp_path / "cloth.obj"
    path.write_text(OBJ.replace("vt 0.1 0\n", "vt 1 0\n").replace("vt 0 0.1\n", "vt 0 1\n").replace("vt 0.1 0.1\n", "vt 1 1\n"))
    with pytest.raises(MeshError, match=r"-90 % strain.*'vt' must be in metres"):
        mesh_from_obj(path)
    path.write_text(OBJ)
    assert mesh_from_obj(path).num_vertices == 4
    spec = {"cloth": {"mesh": "cloth.obj", "translate": [0, 0, 1]}, "duration": 0.02}
    assert parse_scene(spec, base_dir=tmp_path).model.num_vertices == 4


def test_issue_cases_each_give_a_one_line_error_quickly(tmp_path):
    """Issue 11 items 2-4, scene side, through the file reader a user calls."""
    cases = {
        "collision: {stiffness: 1.0e6, friction: -0.3}": r"'collision.friction' must be >= 0",
        "solver: {damping: .nan}": r"'solver.damping' must be a finite number",
        "cloth: {grid: {resolution: 100000}}": r"max_grid_resolution",
        "cloth: {grid: {resolutoin: 8}}": r"did you mean 'resolution'",
        "cloth: {grid: {}, fabirc: paper}": r"did you mean 'fabric'",
        "name: ../../escape": r"'name' must be a simple file name",
        "duration: 1.0e6": r"max_steps",
    }
    for text, match in cases.items():
        path = tmp_path / "s.yaml"
        spec = {"cloth": {"grid": {"resolution": 4}}}
        spec.update(yaml.safe_load(text))
        path.write_text(yaml.safe_dump(spec) if "cloth" not in text else text + "\n")
        with time_limit(3.0), pytest.raises(TryonError, match=match) as info:
            load_scene(path)
        assert "\n" not in str(info.value)
    ok = tmp_path / "ok.yaml"
    ok.write_text("cloth: {grid: {resolution: 4}}\ncollision: {stiffness: 1.0e6}\nduration: 0.02\n")
    assert load_scene(ok).model.collision.stiffness == 1.0e6
    assert not any(p.name == "escape" for p in tmp_path.parent.parent.iterdir())
