"""The try-on path end to end at a coarse edge length: drape, outputs, garment OBJ import,
over-strain, animation and the web viewer (headless Chromium)."""

import json

import numpy as np
import pytest
from PIL import Image

from tryon.cli import main
from tryon.io.mesh_io import read_obj

pytestmark = [pytest.mark.anny, pytest.mark.slow]

COARSE = ["--edge-length", "0.03"]


@pytest.fixture(scope="module")
def drape_dir(tmp_path_factory):
    out = tmp_path_factory.mktemp("drape") / "tshirt"
    rc = main(["drape", "--height-cm", "165", "--weight-kg", "60", "--gender", "female", "--garment", "tshirt",
               "--size", "S", "--fabric", "gray-interlock", *COARSE, "--out", str(out), "--quiet"])
    assert rc == 0
    return out


def _picture(path):
    img = np.asarray(Image.open(path).convert("RGB")).astype(float)
    assert img.shape[0] >= 300 and img.std() > 10, f"{path} looks blank"
    return img


def test_drape_writes_a_believable_tshirt(drape_dir):
    rep = json.loads((drape_dir / "report.json").read_text())
    for key in ("penetration_pct", "max_strain", "wall_s", "mean_strain", "potential_energy", "steps"):
        assert key in rep
    assert rep["penetration_pct"] == 0.0 and rep["vertices_inside"] == 0
    assert rep["self_intersections"] == 0 and rep["body_intersections"] == 0
    assert rep["settled"]
    assert 0.0 < rep["max_strain"] < 0.35 and rep["mean_strain"] < 0.06
    # judged as tryon size and the service judge a size
    assert rep["fit"]["judged_on"] == "simulated drape" and rep["fit"]["fits"] == (not rep["fit"]["why_not"])
    assert rep["fit"]["torso_ease_cm"] > 0
    assert abs(rep["body"]["achieved"]["height_cm"] - 165) < 1.0
    # it rests on the shoulders, not floating: most of it within 3 cm of the skin
    assert rep["mean_skin_distance_mm"] < 30.0
    for name in ("render_front.png", "render_back.png", "render_side.png", "fit_map.png", "pressure_map.png", "pattern.png"):
        _picture(drape_dir / name)
    for name in ("tryon.glb", "body.obj", "pattern.svg", "pattern.json"):
        assert (drape_dir / name).stat().st_size > 100
    garment = read_obj(drape_dir / "garment.obj")
    assert garment.face_uv is not None and len(garment.faces) == rep["mesh"]["garment_faces"]


def test_garment_obj_drapes_like_the_pattern_it_came_from(drape_dir, tmp_path):
    out = tmp_path / "from_obj"
    rc = main(["drape", "--height-cm", "165", "--weight-kg", "60", "--gender", "female",
               "--garment", str(drape_dir / "garment.obj"), "--fabric", "gray-interlock", "--out", str(out), "--quiet"])
    assert rc == 0
    rep = json.loads((out / "report.json").read_text())
    first = json.loads((drape_dir / "report.json").read_text())
    assert rep["size"] is None and rep["penetration_pct"] == 0.0
    assert abs(rep["max_strain"] - first["max_strain"]) < 0.05  # already at rest: it stays as it was
    a = read_obj(out / "garment.obj").vertices
    b = read_obj(drape_dir / "garment.obj").vertices
    moved = np.linalg.norm(a - b, axis=1)
    # it settles a little further (about a centimetre) and a loose hem may swing a few; nothing pops
    assert np.median(moved) < 0.015 and moved.max() < 0.06, (np.median(moved), moved.max())


def test_garment_obj_without_material_coordinates_is_refused(tmp_path, capsys):
    obj = tmp_path / "flat.obj"
    obj.write_text("v 0 0 1\nv 1 0 1\nv 0 1 1\nf 1 2 3\n")
    rc = main(["drape", "--height-cm", "165", "--weight-kg", "60", "--gender", "female", "--garment", str(obj),
               "--out", str(tmp_path / "o"), "--quiet"])
    assert rc == 2
    assert "texture coordinates" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


def test_too_small_garment_on_a_large_body_reports_over_strain(drape_dir, tmp_path):
    out = tmp_path / "tight"
    args = ["drape", "--height-cm", "165", "--bmi", "36", "--gender", "female", "--garment", "tshirt", "--size", "S",
            *COARSE, "--settle-time", "0.2", "--out", str(out), "--quiet"]
    assert main(args) == 2  # refused by default: far too small
    rc = main(args + ["--allow-tight"])
    assert rc == 0
    tight = json.loads((out / "report.json").read_text())
    normal = json.loads((drape_dir / "report.json").read_text())
    assert tight["overstrained_area_pct"] > normal["overstrained_area_pct"] + 20
    assert tight["mean_strain"] > 2 * normal["mean_strain"]
    assert np.isfinite(tight["max_strain"]) and tight["penetration_pct"] < 1.0


@pytest.mark.parametrize("argv,message", [
    (["--bmi", "60"], "outside the supported range"),
    (["--weight-kg", "60", "--garment", "cape"], "unknown garment"),
    (["--weight-kg", "60", "--size", "XXXL"], "unknown size"),
    (["--weight-kg", "60", "--fabric", "chainmail"], "chainmail"),
])
def test_bad_drape_requests_get_one_clear_error(tmp_path, capsys, argv, message):
    rc = main(["drape", "--height-cm", "170", "--gender", "male", *argv, "--out", str(tmp_path / "o"), "--quiet"])
    assert rc == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1
    assert not (tmp_path / "o").exists()


def test_animate_follows_the_body(drape_dir):
    rc = main(["animate", str(drape_dir), "--motion", "arm-raise", "--duration", "0.3", "--quiet"])
    assert rc == 0
    out = drape_dir / "animation-arm-raise"
    rep = json.loads((out / "report.json").read_text())
    metrics = json.loads((out / "metrics.json").read_text())
    assert rep["frames"] == len(metrics) >= 8
    assert rep["max_penetration_pct"] < 1.0 and rep["intersections"] == 0
    frames = np.load(out / "frames.npz")
    assert frames["positions"].shape[0] == frames["body_vertices"].shape[0] == rep["frames"]
    assert np.abs(frames["body_vertices"][-1] - frames["body_vertices"][0]).max() > 0.01  # the body moved
    gif = Image.open(out / "preview.gif")
    assert gif.n_frames == rep["frames"]
    assert not (drape_dir / "animation-arm-raise.checkpoint").exists()


def test_animate_refuses_a_folder_without_a_drape(tmp_path, capsys):
    rc = main(["animate", str(tmp_path), "--motion", "walk", "--quiet"])
    assert rc == 2
    assert "holds no drape" in capsys.readouterr().err


def test_viewer_draws_the_garment_in_headless_chromium(drape_dir, tmp_path):
    from tryon.viewer import screenshot_viewer, write_viewer

    viewer = write_viewer(drape_dir)
    meta = json.loads((viewer / "scene.json").read_text())
    assert meta["garment"]["vertices"] > 100 and meta["frames"] >= 2 and not meta["predicted"]
    status = screenshot_viewer(viewer, tmp_path / "plain.png", mode="plain")
    assert status.startswith("ready"), status
    img = _picture(tmp_path / "plain.png")
    r, b = img[..., 0], img[..., 2]
    # the garment in its fabric's colour, shaded: the same chromaticity, darker than the page
    cloth = np.asarray(meta["colors"]["cloth"], float)
    rgb = img[..., :3].astype(float)
    chroma = rgb / np.maximum(rgb.sum(-1, keepdims=True), 1.0)
    garment = (np.abs(chroma - cloth / cloth.sum()).max(-1) < 0.04) & (rgb.sum(-1) > 30) & (rgb.sum(-1) < 600)
    garment[:220, :400] = False  # the info panel's text
    skin = (r > b + 25) & (r > 100)
    assert garment.mean() > 0.02, "no garment drawn"
    assert skin.mean() > 0.02, "no body drawn"
    # fit-map colouring changes the picture
    screenshot_viewer(viewer, tmp_path / "strain.png", mode="strain")
    assert np.abs(_picture(tmp_path / "strain.png") - img).mean() > 1.0


def test_view_command_writes_a_screenshot(drape_dir, tmp_path, capsys):
    png = tmp_path / "shot.png"
    rc = main(["view", str(drape_dir), "--screenshot", str(png), "--mode", "pressure"])
    assert rc == 0 and "ready" in capsys.readouterr().out
    _picture(png)


def test_time_parallel_walk_carries_the_drape_detail_across_segment_starts(drape_dir):
    """The coarse garment (its own pattern, 1.5x the edge) carries the drape's detail over
    it in local frames: upsampling its start state gives the drape back exactly, later
    start states stay free of crossings, and the joined run matches the serial one."""
    from tryon.drape.animate import animation_scene
    from tryon.parallel import ParallelOptions, simulate_time_parallel
    from tryon.parallel.coarse import CoarseRun
    from tryon.parallel.hierarchy import build_hierarchy
    from tryon.parallel.recovery import obstacle_crossings, self_intersecting_vertices, start_positions
    from tryon.sim.integrator import ImplicitEulerSolver
    from tryon.sim.runner import simulate

    scene = animation_scene(drape_dir, "walk", dt=0.01, duration=0.3, blend_time=0.1)
    hier = build_hierarchy(scene)
    assert hier.detail is not None and hier.kind.startswith("coarsen")
    assert np.abs(hier.upsample_positions(hier.coarse.model.mesh.x.numpy()) - scene.model.mesh.x.numpy()).max() < 1e-9
    run = CoarseRun(hier)
    while run.position < 20:
        run.advance()
    x, keep = start_positions(hier, run.states[20][0], 0.2)
    assert len(self_intersecting_vertices(hier, x)) == 0 and obstacle_crossings(hier, x, 0.2) == 0
    assert 0.0 <= keep.min() and keep.mean() > 0.5

    serial = simulate(scene, progress=False)
    par = simulate_time_parallel(scene, ParallelOptions(workers=2, segments=2, partition="uniform", mode="local"),
                                 progress=False, hierarchy=hier)
    assert par.positions.shape == serial.positions.shape and par.summary["intersections"] == 0
    seg = par.segments[1]
    solver = ImplicitEulerSolver(scene.model, scene.options)
    state = scene.model.initial_state()
    for _ in range(seg.start):
        state, _ = solver.step(state, scene.dt)
    off = np.linalg.norm(seg.x_start - state.x.numpy(), axis=1)
    assert np.median(off) < 0.005, np.median(off)  # about 2 mm here; about 9 mm without the carried detail

    # the cross-fade spreads the boundary's jump: no joined frame moves much more than serial
    jump = np.linalg.norm(seg.x_start - par.segments[0].x_end, axis=1).mean()
    k = int(np.searchsorted(par.times, seg.start * scene.dt - 1e-9))
    window = range(k - 1, min(k + 6, len(par.times) - 1))
    excess = [np.linalg.norm((par.positions[i + 1] - par.positions[i]) - (serial.positions[i + 1] - serial.positions[i]),
                             axis=1).mean() for i in window]
    assert sum(par.summary["parallel"]["crossfade"]["blended_frames"].values()) >= 3
    assert max(excess) < 0.75 * jump, (max(excess), jump)  # 0.67 and 1.39 mm here; at least the jump without it
