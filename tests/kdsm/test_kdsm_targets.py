"""Each method's targets on a small pose dataset (the KDSM paper's Table 1): the baseline's
offsets and Method 1 rebuild the cloth (Method 1 exactly wherever the cloth is inside the
posed volume), Method 2 and the hybrid trade a little error for targets that change
less between poses, and all beat skinning the rest drape."""

import json

import numpy as np
import pytest

from tryon.dataset.poses import PoseDatasetSpec, load_pose_dataset, make_pose_dataset
from tryon.errors import TryonError
from tryon.kdsm.animate import check_garment
from tryon.kdsm.embed import find_parents
from tryon.kdsm.evaluate import generation_table, sequence_targets
from tryon.kdsm.rig import KdsmRig

pytestmark = [pytest.mark.anny, pytest.mark.slow]


@pytest.fixture(scope="module")
def poses(tmp_path_factory):
    out = tmp_path_factory.mktemp("kdsm") / "poses"
    make_pose_dataset(PoseDatasetSpec(count=2, frames=8, edge_length=0.03, seed=5), out, progress=False)
    data = load_pose_dataset(out)
    rows = data.rows()
    assert len(rows) >= 1
    rig = KdsmRig.build(data.rest.garment.vertices, data.rest.garment.faces, data.rest.shape(), cell=0.025)
    return data, rows, rig, out


def test_targets_rebuild_the_cloth(poses):
    data, rows, rig, folder = poses
    x, p = data.arrays["x"][rows[0]].astype(float), data.arrays["pose"][rows[0]]
    res = sequence_targets(rig, x, p)
    assert np.abs(res["jin-uvn"]["rebuilt"] - x).max() < 1e-9
    for f in range(len(x)):
        posed = rig.skin.pose(rig.volume.vertices, rig.transforms(p[f]))
        inside = find_parents(x[f], posed, rig.volume.tets).count(len(x[f])) > 0
        assert inside.mean() > 0.98
        assert np.abs(res["kdsm-method1"]["rebuilt"][f][inside] - x[f][inside]).max() < 1e-9
    # at the first pose after the blend from the rest drape's pose, d is where the cloth moved in material space
    assert np.isfinite(res["kdsm-hybrid"]["target"]).all()
    # the hybrid's smoothing: none rebuilds the cloth as exactly as Method 1; more gives a smoother d that rebuilds less
    G = rig.transforms(p[-1])
    inside = find_parents(x[-1], rig.skin.pose(rig.volume.vertices, G), rig.volume.tets).count(len(x[-1])) > 0
    err, rough = [], []
    for s in (0.0, 0.25, 1.0):
        d = rig.target("kdsm-hybrid", x[-1], G, smoothing=s)
        err.append(np.linalg.norm(rig.positions("kdsm-hybrid", d, G)[inside] - x[-1][inside], axis=1).mean())
        rough.append(np.linalg.norm(d[rig.faces[:, 0]] - d[rig.faces[:, 1]], axis=1).mean())
    assert err[0] < 1e-9 < err[1] < err[2] and rough[0] > rough[1] > rough[2]


def test_hybrid_targets_are_cached_apart_for_each_smoothing(poses, tmp_path):
    from tryon.kdsm.train import KdsmTrainConfig, examples

    data, rows, rig, folder = poses
    smooth = examples(data, rig, "kdsm-hybrid", tmp_path / "cache", progress=False, smoothing=1.0)
    exact = examples(data, rig, "kdsm-hybrid", tmp_path / "cache", progress=False, smoothing=0.0)
    assert len(list((tmp_path / "cache").glob("kdsm-hybrid-*"))) == 2
    assert np.abs(smooth["target"] - exact["target"]).max() > 1e-4
    again = examples(data, rig, "kdsm-hybrid", tmp_path / "cache", progress=False, smoothing=0)   # read back, same key
    assert np.array_equal(again["target"], exact["target"]) and len(list((tmp_path / "cache").glob("*"))) == 2
    with pytest.raises(TryonError, match="kdsm-hybrid"):
        KdsmTrainConfig(method="jin-uvn", smoothing=0.0).validate()


def test_generation_table_orders_the_methods_as_the_paper(poses):
    data, rows, rig, folder = poses
    rows = {r["method"]: r for r in generation_table(rig, data.arrays["x"][rows], data.arrays["pose"][rows])}
    assert set(rows) == {"skinning", "jin-uvn", "kdsm-method1", "kdsm-method2", "kdsm-hybrid"}
    assert rows["kdsm-method1"]["generation_mean_error_cm"] < 0.05
    assert rows["kdsm-method2"]["generation_mean_error_cm"] > rows["kdsm-hybrid"]["generation_mean_error_cm"]
    assert rows["kdsm-hybrid"]["max_delta_d_cm"] <= rows["kdsm-method1"]["max_delta_d_cm"] + 1e-9
    assert rows["skinning"]["generation_mean_error_cm"] > rows["kdsm-hybrid"]["generation_mean_error_cm"]
    assert "pose_spread_cm" not in rows["skinning"]


def test_target_spread_over_poses(poses):
    data, rows, rig, folder = poses
    x, p = data.arrays["x"][rows], data.arrays["pose"][rows]
    table = {r["method"]: r for r in generation_table(rig, x, p)}
    targets = [sequence_targets(rig, x[s].astype(float), p[s]) for s in range(len(x))]
    for method in ("jin-uvn", "kdsm-hybrid"):    # against the spread of the targets computed directly
        t = np.concatenate([res[method]["target"] for res in targets])
        per_vertex = 100.0 * np.sqrt(((t - t.mean(0)) ** 2).sum(-1).mean(0))
        assert table[method]["pose_spread_cm"] == pytest.approx(per_vertex.mean(), rel=1e-6)
        assert table[method]["pose_spread_p95_cm"] == pytest.approx(np.percentile(per_vertex, 95), rel=1e-6)
        assert table[method]["pose_spread_cm"] > 0.01
    # Method 2's d is the offsets turned by the rest pose's orthonormal frames and shifted: the same spread
    assert table["kdsm-method2"]["pose_spread_cm"] == pytest.approx(table["jin-uvn"]["pose_spread_cm"], rel=1e-6)


def test_generation_table_smooths_the_hybrid_as_asked(poses):
    data, rows, rig, folder = poses
    x, p = data.arrays["x"][rows[:1]], data.arrays["pose"][rows[:1]]
    def hybrid_rows(smoothings):
        return [r for r in generation_table(rig, x, p, smoothings=smoothings) if r["method"] == "kdsm-hybrid"]

    exact, smooth = hybrid_rows((0.0, 1.0))   # one row per smoothing, from one embedding of each pose
    assert (exact["smoothing"], smooth["smoothing"]) == (0.0, 1.0)
    assert exact["generation_mean_error_cm"] < smooth["generation_mean_error_cm"]
    assert hybrid_rows((1.0,)) == [smooth]    # as if it were the only one
    # one embedding smoothed per value gives the targets training learns (rig.target at that smoothing)
    G = rig.transforms(p[0, -1])
    assert np.allclose(sequence_targets(rig, x[0], p[0], smoothing=1.0)["kdsm-hybrid"]["target"][-1],
                       rig.target("kdsm-hybrid", x[0, -1].astype(np.float64), G, smoothing=1.0), atol=1e-12)


def test_a_checkpoint_without_smoothing_resumes_only_as_it_was_trained(poses, tmp_path, capsys):
    import torch

    from tryon.cli import main
    from tryon.kdsm.rig import HYBRID_SMOOTHING, SMOOTHING_BEFORE_SETTING
    from tryon.kdsm.train import CHECKPOINT, KdsmTrainConfig, train_kdsm

    data, rows, rig, folder = poses
    old = KdsmTrainConfig(method="kdsm-hybrid", epochs=3, batch=4, cell=0.025, smoothing=SMOOTHING_BEFORE_SETTING)
    assert train_kdsm(folder, tmp_path / "m", old, progress=False, max_epochs_this_run=1) is None
    ckpt = torch.load(tmp_path / "m" / CHECKPOINT, weights_only=True)   # as saved before smoothing was a setting
    ckpt["config"] = json.dumps({k: v for k, v in json.loads(ckpt["config"]).items() if k != "smoothing"})
    torch.save(ckpt, tmp_path / "m" / CHECKPOINT)
    today = KdsmTrainConfig(method="kdsm-hybrid", epochs=3, batch=4, cell=0.025)
    assert today.smoothing == HYBRID_SMOOTHING != SMOOTHING_BEFORE_SETTING
    with pytest.raises(TryonError, match="smoothing: 1.0 there, 0.25 asked"):
        train_kdsm(folder, tmp_path / "m", today, progress=False)
    assert len(list((tmp_path / "m" / "cache").glob("kdsm-hybrid-*"))) == 1   # refused before computing targets
    assert train_kdsm(folder, tmp_path / "m", old, progress=False, max_epochs_this_run=1) is None   # resumed
    # the command line refuses --smoothing for a method without it, and says the default
    assert main(["train", "kdsm", "--data", str(folder), "--method", "jin-uvn", "--smoothing", "0.25",
                 "--out", str(tmp_path / "j")]) == 2
    assert "kdsm-hybrid's targets only" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["train", "kdsm", "--help"])
    assert f"default {HYBRID_SMOOTHING:g};" in " ".join(capsys.readouterr().out.split())


def test_table_1_shows_the_hybrid_at_each_benched_smoothing():
    from types import SimpleNamespace

    from tryon.bench.kdsm import hybrid_smoothings
    from tryon.kdsm.rig import HYBRID_SMOOTHING

    def model(method, smoothing=None):
        return SimpleNamespace(method=method, smoothing=smoothing)

    assert hybrid_smoothings([model("jin-uvn")]) == [HYBRID_SMOOTHING]
    assert hybrid_smoothings([model("kdsm-hybrid", 1.0), model("jin-uvn"), model("kdsm-hybrid", 0.25),
                              model("kdsm-hybrid", 1.0)]) == [1.0, 0.25]


def test_checkpoints_made_before_a_setting_resume_with_what_training_did_then():
    from dataclasses import asdict

    from tryon.kdsm.model import KdsmModel
    from tryon.kdsm.rig import HYBRID_SMOOTHING, SMOOTHING_BEFORE_SETTING
    from tryon.kdsm.train import KdsmTrainConfig, _resumed_config

    old_hybrid = {k: v for k, v in asdict(KdsmTrainConfig(method="kdsm-hybrid")).items() if k != "smoothing"}
    assert _resumed_config(old_hybrid)["smoothing"] == SMOOTHING_BEFORE_SETTING != HYBRID_SMOOTHING
    assert _resumed_config(old_hybrid) == asdict(KdsmTrainConfig(method="kdsm-hybrid", smoothing=SMOOTHING_BEFORE_SETTING))
    # the other methods have no smoothing: whatever their checkpoint saved, they resume under today's default
    jin = {**asdict(KdsmTrainConfig(method="jin-uvn")), "smoothing": 1.0}
    assert _resumed_config(jin) == asdict(KdsmTrainConfig(method="jin-uvn"))
    assert _resumed_config({k: v for k, v in jin.items() if k != "schedule"})["schedule"] == "constant"
    card = {"config": old_hybrid}
    assert KdsmModel("kdsm-hybrid", None, None, None, None, None, None, None, card=card).smoothing == SMOOTHING_BEFORE_SETTING
    card = {"config": {**old_hybrid, "smoothing": 0.5}}
    assert KdsmModel("kdsm-hybrid", None, None, None, None, None, None, None, card=card).smoothing == 0.5
    assert KdsmModel("jin-uvn", None, None, None, None, None, None, None, card=card).smoothing is None


def test_training_learns_saves_and_resumes_exactly(poses, tmp_path):
    from tryon.kdsm.model import KdsmModel
    from tryon.kdsm.train import KdsmTrainConfig, train_kdsm

    data, rows, rig, folder = poses
    cfg = KdsmTrainConfig(method="kdsm-hybrid", epochs=6, batch=4, cell=0.025)
    whole = train_kdsm(folder, tmp_path / "whole", cfg, progress=False)
    hist = [h["train_loss"] for h in whole.card["history"]]
    assert hist[-1] < 0.7 * hist[0]
    assert whole.card["metrics"] and all(np.isfinite(m["mean_error_cm"]) for m in whole.card["metrics"].values())
    # stopped after 3 epochs, then resumed: the same weights as the run that never stopped
    assert train_kdsm(folder, tmp_path / "split", cfg, progress=False, max_epochs_this_run=3) is None
    resumed = train_kdsm(folder, tmp_path / "split", cfg, progress=False)
    assert [h["val_mean_error_cm"] for h in resumed.card["history"]] == [h["val_mean_error_cm"] for h in whole.card["history"]]
    for k, v in whole.weights.items():
        assert np.array_equal(v, resumed.weights[k]), k
    # the model file alone predicts the garment
    model = KdsmModel.load(tmp_path / "whole" / "model.npz")
    x = model.predict(data.arrays["pose"][rows[0]][-1])
    assert x.shape == rig.x0.shape and np.isfinite(x).all()
    assert np.linalg.norm(x - data.arrays["x"][rows[0]][-1], axis=1).mean() < 0.1


def test_enclosed_volume_caps_the_openings():
    import trimesh

    from tryon.kdsm.evaluate import boundary_loops, enclosed_volume

    m = trimesh.creation.cylinder(radius=0.1, height=0.3, sections=48)
    open_faces = m.faces[np.abs(m.face_normals[:, 2]) < 0.5]
    assert len(boundary_loops(open_faces)) == 2
    assert enclosed_volume(m.vertices, open_faces) == pytest.approx(m.volume, rel=1e-9)
    moved = m.vertices @ np.array([[0, -1, 0], [1, 0, 0], [0, 0, 1.0]]).T + 0.3
    assert enclosed_volume(moved, open_faces) == pytest.approx(m.volume, rel=1e-9)


def test_the_kdsm_bench_writes_every_table(poses, tmp_path):
    import json

    from tryon.bench.kdsm import model_labels, run_kdsm_bench
    from tryon.kdsm.train import KdsmTrainConfig, train_kdsm

    data, rows, rig, folder = poses
    train_kdsm(folder, tmp_path / "jin", KdsmTrainConfig(method="jin-uvn", epochs=2, batch=4, cell=0.025), progress=False)
    recs = run_kdsm_bench(tmp_path / "b" / "kdsm.json", folder, [tmp_path / "jin" / "model.npz"], progress=False)
    learned = [r for r in recs if r["table"] == "learned"]
    assert {r["method"] for r in learned} == {"skinning", "jin-uvn"}
    for r in learned:
        assert {"method", "split", "mean_error_cm", "std_error_cm", "volume_error_cm3", "inference_ms"} <= set(r)
        assert np.isfinite(r["mean_error_cm"]) and r["inference_ms"] > 0
    quality = [r for r in recs if r["table"] == "volume-quality"]
    assert len(quality) == 1 and quality[0]["poses"] > 0 and 0 <= quality[0]["arm_torso_overlap_pct_mean"] < 100
    by_source = [r for r in recs if r["table"] == "learned-by-source"]
    for r in learned:   # every frame of a split is in exactly one kind of sequence
        parts = [b for b in by_source if b["method"] == r["method"] and b["split"] == r["split"]]
        assert sum(b["frames"] for b in parts) == r["frames"]
        assert sum(b["frames"] * b["mean_error_cm"] for b in parts) == pytest.approx(r["frames"] * r["mean_error_cm"])
    assert json.loads((tmp_path / "b" / "kdsm.json").read_text())
    assert all(r["label"] == r["method"] for r in learned)
    # two models of one method are told apart by their folders
    assert model_labels(["a/h/model.npz", "a/h2/model.npz", "j/model.npz"], ["kdsm-hybrid", "kdsm-hybrid", "jin-uvn"]) == [
        "kdsm-hybrid (h)", "kdsm-hybrid (h2)", "jin-uvn"]


def test_animate_with_a_kdsm_model_on_another_body_and_triangulation(poses, tmp_path, capsys):
    import json

    from tryon.cli import main
    from tryon.drape.animate import load_drape
    from tryon.kdsm.train import KdsmTrainConfig, train_kdsm

    data, rows, rig, folder = poses
    train_kdsm(folder, tmp_path / "m", KdsmTrainConfig(method="kdsm-hybrid", epochs=2, batch=4, cell=0.025), progress=False)
    # another body, and the pattern meshed at 4 cm where the model's dataset used 3 cm
    drape = tmp_path / "drape"
    assert main(["drape", "--height-cm", "170", "--weight-kg", "66", "--gender", "female", "--size", "M", "--edge-length",
                 "0.04", "--out", str(drape), "--quiet"]) == 0
    assert main(["animate", str(drape), "--motion", "arm-raise", "--duration", "0.5", "--method", "kdsm", "--model",
                 str(tmp_path / "m" / "model.npz"), "--quiet"]) == 0
    out = drape / "animation-arm-raise"
    rep = json.loads((out / "report.json").read_text())
    assert rep["transferred_to_another_body"] and rep["frames"] == 16 and rep["ms_per_frame"] > 0
    frames = np.load(out / "frames.npz")
    n = len(load_drape(drape)["x"])
    assert frames["positions"].shape == (16, n, 3) and n < len(rig.x0) and np.isfinite(frames["positions"]).all()
    # what the network put inside the body is moved out of it
    assert rep["pushed_out"] and rep["pushed_out_vertices_pct_max"] >= 0
    assert max(m["penetration_pct"] for m in json.loads((out / "metrics.json").read_text())) < 0.5
    # the viewer plays it like a simulated animation
    from tryon.viewer import write_viewer

    scene = json.loads((write_viewer(drape, animation="arm-raise") / "scene.json").read_text())
    assert scene["frames"] == 16 and scene["garment"]["vertices"] == n
    assert any("kdsm" in line and "ms per frame" in line for line in scene["info"]) and scene["predicted"]
    _live_posing_of(drape, tmp_path / "m" / "model.npz", n, tmp_path, capsys)
    # the bench's held-out motion: the model against the simulated animation of the same drape, with a picture
    from PIL import Image

    from tryon.bench.kdsm import _at_times, heldout_motion_records
    from tryon.body.pose_sampling import random_motion

    random_motion(data.rest.shape(), seed=99, seconds=0.2).save(tmp_path / "motion.npz")
    recs = heldout_motion_records([tmp_path / "m" / "model.npz"], drape, tmp_path / "motion.npz", tmp_path / "held",
                                  progress=False, picture=tmp_path / "held.png", from_rest=data.manifest.spec,
                                  from_rest_frames=1)
    assert len(recs) == 2 and recs[0]["transferred_to_another_body"] and recs[0]["frames"] == 22
    assert 0 < recs[0]["mean_error_cm"] <= recs[0]["max_frame_error_cm"] < 20
    assert Image.open(tmp_path / "held.png").size == (720, 480)   # simulated and the one model side by side
    # the floor of a pose-to-cloth model: the simulator's cloth for a pose of the motion, from rest, against the animation
    gap, model = recs[1], recs[0]
    assert gap["method"] == "simulation-from-rest" and gap["frames"] == 1 and gap["failed_frame_times_s"] == []
    assert gap["frame_times_s"] == [pytest.approx(0.5)]   # the first frame after the blend
    assert gap["fabric"] == load_drape(drape)["request"]["fabric"]
    assert 0 < gap["mean_error_cm"] < 10 and 0 < model["from_rest_error_cm"] < 20
    # the model's distances to the animation and to the cloth from rest, and theirs to each other, at the same frame
    assert abs(model["sampled_frames_error_cm"] - model["from_rest_error_cm"]) <= gap["mean_error_cm"] + 1e-9
    got = np.load(tmp_path / "held" / "model0-m" / "frames.npz")
    sim = np.load(tmp_path / "held" / "simulated" / "frames.npz")
    at = np.flatnonzero(np.isclose(got["times"], 0.5))[0]
    truth = _at_times(sim["positions"], sim["times"], got["times"][at:at + 1])[0]
    assert model["sampled_frames_error_cm"] == pytest.approx(
        100 * np.linalg.norm(got["positions"][at] - truth, axis=1).mean(), rel=1e-6)


def _live_posing_of(drape, model_path, n, tmp_path, capsys):
    """`tryon view --live`: the sliders' pose predicted by the model, served to the page."""
    from tryon.body.pose import matrix_to_axis_angle
    from tryon.body.pose_sampling import pose_from_angles
    from tryon.cli import main
    from tryon.errors import TryonError
    from tryon.kdsm.live import LivePoser

    poser = LivePoser(drape, model_path)
    start, raised = poser.frame({}), poser.frame({"arm_elevation.L": 120.0, "knee_flexion.R": 40.0})
    pose = matrix_to_axis_angle(pose_from_angles(poser.shape, poser.angles({"arm_elevation.L": 120.0, "knee_flexion.R": 40.0})))
    rig = poser.predictor.rig
    assert np.allclose(raised["body"], rig.body(rig.transforms(pose)))
    predicted = poser.predictor.model.predict(pose, poser.predictor.net)
    moved = np.linalg.norm(raised["garment"] - predicted, axis=1)
    assert raised["garment"].shape == (n, 3) and np.median(moved) == 0.0   # only what lay in the body was pushed out
    assert np.linalg.norm(raised["garment"] - start["garment"], axis=1).max() > 0.03 and raised["ms"] > 0
    assert raised["strain"].shape == (n,) and np.isfinite(raised["strain"]).all()
    with pytest.raises(TryonError, match="unknown joint angle"):
        poser.frame({"tail": 3.0})
    with pytest.raises(TryonError, match="outside the range"):
        poser.frame({"arm_elevation.L": 170.0})
    assert main(["view", str(drape), "--pose", "arm_elevation.L=120"]) == 2   # --pose belongs to --live
    assert main(["view", str(drape), "--live", "--model", str(model_path), "--pose", "tail=3"]) == 2
    assert "unknown joint angle(s) tail" in capsys.readouterr().err
    # the page asks for the pose its URL sets, and draws what the server predicted
    from types import SimpleNamespace

    from tryon.viewer import screenshot_viewer, write_viewer

    asked = []
    recording = SimpleNamespace(method=poser.method, controls=poser.controls,
                                frame=lambda values: asked.append(values) or poser.frame(values))
    status = screenshot_viewer(write_viewer(drape, force=True), tmp_path / "live.png", live=recording,
                               pose={"arm_elevation.L": 120.0, "knee_flexion.R": 40.0})
    assert status.startswith("ready: live"), status
    assert asked and asked[0]["arm_elevation.L"] == 120.0 and asked[0]["knee_flexion.R"] == 40.0


def test_a_model_reads_its_images_on_another_triangulation(poses, tmp_path):
    """Flipping interior edges of the model's own mesh (what another machine's Delaunay can
    do) changes nothing in the prediction: the network is read at material coordinates."""
    from tryon.kdsm.model import KdsmModel
    from tryon.kdsm.train import KdsmTrainConfig, train_kdsm

    data, rows, rig, folder = poses
    train_kdsm(folder, tmp_path / "j", KdsmTrainConfig(method="jin-uvn", epochs=1, batch=4, cell=0.025), progress=False)
    g = data.rest.garment
    faces, corner_uv = _flip_interior_edges(g.faces, g.corner_uv, g.face_panel, g.seam_vertices, count=40)
    assert (faces != g.faces).any(axis=1).sum() >= 40
    pose = data.arrays["pose"][rows[0]][-1]
    for path in (tmp_path / "j" / "model.npz", tmp_path / "j" / "best.npz"):
        model = KdsmModel.load(path)
        moved, how = model.on_drape(g.vertices, faces, corner_uv, g.face_panel, data.rest.shape())
        assert how == "retriangulated" and np.array_equal(moved.rig.faces, faces)
        assert np.abs(moved.predict(pose) - model.predict(pose)).max() < 1e-6
    # a garment of another size is refused by name
    from tryon.dataset.drapes import size_pattern
    from tryon.garment.triangulate import triangulate_pattern

    other = triangulate_pattern(size_pattern("tshirt", "female", "XL")[2], 0.03)
    with pytest.raises(TryonError, match="pattern"):
        model.atlas.on_garment(other.faces, other.corner_uv, other.panel_of_vertex[other.faces[:, 0]])
    with pytest.raises(TryonError, match="tshirt M"):
        check_garment(KdsmModel.load(tmp_path / "j" / "model.npz"), {"request": {"garment": "tshirt", "size": "XL", "fabric": "gray-interlock"}}, "m.npz")


def _flip_interior_edges(faces, corner_uv, face_panel, seam, count):
    """Flip `count` edges shared by two faces of one panel, away from seams."""
    faces, corner_uv = faces.copy(), corner_uv.copy()
    seam = set(np.asarray(seam).tolist())
    owner = {}
    for f, tri in enumerate(faces):
        for k in range(3):
            owner[(tri[k], tri[(k + 1) % 3])] = (f, k)
    used, flipped = set(), 0
    for (a, b), (f, k) in list(owner.items()):
        if flipped == count or (b, a) not in owner or f in used:
            continue
        h, j = owner[(b, a)]
        c, d = faces[f, (k + 2) % 3], faces[h, (j + 2) % 3]
        if h in used or face_panel[f] != face_panel[h] or {a, b, c, d} & seam:
            continue
        uv = {faces[f, i]: corner_uv[f, i].copy() for i in range(3)} | {faces[h, i]: corner_uv[h, i].copy() for i in range(3)}
        faces[f], faces[h] = (a, d, c), (d, b, c)
        corner_uv[f], corner_uv[h] = [uv[v] for v in (a, d, c)], [uv[v] for v in (d, b, c)]
        used |= {f, h}
        flipped += 1
    return faces, corner_uv


def test_mirrored_examples_are_the_mirror_images(poses):
    from tryon.body.pose import axis_angle, bone_transforms, skin
    from tryon.kdsm.mirror import REFLECT, MirrorMap, mirror_pose
    from tryon.kdsm.train import examples

    data, rows, rig, folder = poses
    g, shape = data.rest.garment, data.rest.shape()
    m = MirrorMap.build(g.vertices, g.faces, g.corner_uv, g.face_panel)
    assert m.rest_error_m < 0.004                      # the rest drape mirrors onto itself
    pose = data.arrays["pose"][rows[0]][-1].astype(float)
    mirrored = mirror_pose(pose, shape.bone_labels)
    assert np.abs(mirror_pose(mirrored, shape.bone_labels) - pose).max() < 1e-12
    body = skin(shape.vertices, shape.weight_index, shape.weight, bone_transforms(shape, axis_angle(pose))).numpy()
    body_m = skin(shape.vertices, shape.weight_index, shape.weight, bone_transforms(shape, axis_angle(mirrored))).numpy()
    from scipy.spatial import cKDTree

    assert cKDTree(body_m).query(body @ REFLECT.T)[0].max() < 1e-6   # the mirrored pose is the mirrored body
    x = data.arrays["x"][rows[0]][-1].astype(float)
    assert np.linalg.norm(m.cloth(m.cloth(x)) - x, axis=1).mean() < 0.002
    plain, both = examples(data, rig, "jin-uvn"), examples(data, rig, "jin-uvn", mirror=True)
    train = (plain["split"] == "train").sum()
    assert len(both["split"]) == len(plain["split"]) + train and both["mirrored"].sum() == train
    assert np.array_equal(both["target"][~both["mirrored"]], plain["target"])
