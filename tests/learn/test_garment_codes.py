"""The garment autoencoder on tiny data: surface clouds, the two levels, Chamfer, and a
training run that learns, resumes and ships a model file."""

import numpy as np
import torch

from tryon.learn.garment_codes import CodeConfig, GarmentCodes, centred_cloud, chamfer, farthest_points, surface_points
from tryon.learn.train_garment_codes import Clouds, CodeTrainConfig, load_codes_model, train_on_clouds

TINY = CodeConfig(cloud=256, reps=16, patch=16, code=16, width=32)


def _tube(radius: float, length: float, flare: float = 0.0, n: int = 24, m: int = 8):
    """An open tube (a sleeve or a skirt: flare widens its lower end)."""
    a = np.linspace(0, 2 * np.pi, n, endpoint=False)
    z = np.linspace(0, -length, m)
    r = radius + flare * (-z / length)
    x = np.stack([np.outer(r, np.cos(a)), np.outer(r, np.sin(a)), np.repeat(z[:, None], n, 1)], -1).reshape(-1, 3)
    faces = []
    for i in range(m - 1):
        for j in range(n):
            p, q = i * n + j, i * n + (j + 1) % n
            faces += [(p, q, p + n), (q, q + n, p + n)]
    return x, np.array(faces)


def test_surface_points_lie_on_the_mesh_spread_by_area():
    x, faces = _tube(0.2, 0.6)
    p = surface_points(x, faces, 4000, np.random.default_rng(0))
    radius = np.linalg.norm(p[:, :2], axis=1)
    assert radius.max() <= 0.2 + 1e-6 and radius.min() > 0.2 * np.cos(np.pi / 24) - 1e-6
    upper = (p[:, 2] > -0.3).mean()
    assert 0.45 < upper < 0.55  # a straight tube's halves hold equal area
    c = centred_cloud(x, faces, np.random.default_rng(0), 500)
    assert np.abs(c.mean(0)).max() < 1e-6


def test_farthest_points_spread_and_chamfer_measures_distance():
    x, faces = _tube(0.2, 0.6)
    cloud = torch.from_numpy(surface_points(x, faces, 1000, np.random.default_rng(1)))[None]
    idx = farthest_points(cloud, 32)[0]
    assert len(set(idx.tolist())) == 32
    picked = cloud[0, idx]
    spread = torch.cdist(picked, picked) + 10 * torch.eye(32)
    random = cloud[0, :32]
    assert spread.min() > (torch.cdist(random, random) + 10 * torch.eye(32)).min()
    assert float(chamfer(cloud, cloud)) < 1e-4  # cdist by matrix products: round-off of 0.1 mm at most
    assert 0.002 < float(chamfer(cloud, cloud + torch.tensor([0.0, 0.0, 0.01]))) <= 0.01 + 1e-4


def _clouds(count: int = 24) -> Clouds:
    rng = np.random.default_rng(0)
    points, kinds, splits = [], [], []
    for i in range(count):
        flare = 0.15 if i % 2 else 0.0
        x, faces = _tube(rng.uniform(0.12, 0.25), rng.uniform(0.4, 0.7), flare)
        points.append(centred_cloud(x, faces, rng, TINY.cloud))
        kinds.append("skirt" if flare else "sleeve")
        splits.append("val" if i >= count - 4 else "train")
    return Clouds(np.stack(points), np.array(kinds), np.array(splits))


def test_training_learns_the_shapes_resumes_and_writes_the_model(tmp_path):
    clouds = _clouds()
    untrained = GarmentCodes(TINY)
    with torch.no_grad():
        before = float(untrained.loss(torch.from_numpy(clouds.points[-4:]))[1].mean())
    card = train_on_clouds(clouds, tmp_path / "m", CodeTrainConfig(epochs=30, batch=8, lr=3e-3), TINY, progress=False)
    assert card["best_val_chamfer_cm"] < 0.5 * 100 * before
    model, saved = load_codes_model(tmp_path / "m" / "garment-codes.npz")
    assert saved["best_val_chamfer_cm"] == card["best_val_chamfer_cm"] and model.config == TINY
    # one latent space for both kinds: a skirt's code lies apart from a sleeve's
    with torch.no_grad():
        codes = model.encode(torch.from_numpy(clouds.points))
    skirt = clouds.garment == "skirt"
    assert codes[skirt].mean(0).sub(codes[~skirt].mean(0)).norm() > 0
    # stopped after 20 epochs then resumed to 30: the same model as the run straight through
    train_on_clouds(clouds, tmp_path / "r", CodeTrainConfig(epochs=20, batch=8, lr=3e-3), TINY, progress=False)
    resumed = train_on_clouds(clouds, tmp_path / "r", CodeTrainConfig(epochs=30, batch=8, lr=3e-3), TINY,
                              progress=False)
    straight = [h["val_chamfer_cm"] for h in card["history"]]
    assert np.allclose([h["val_chamfer_cm"] for h in resumed["history"]], straight, rtol=1e-5)


def test_the_shipped_model_loads_and_codes_a_garment():
    from tryon.cli.learned import SHIPPED_CODES

    model, card = load_codes_model(SHIPPED_CODES)
    assert card["test"]["chamfer_cm"] < 3.0 and card["drapes"]["train"] > 100
    x, faces = _tube(0.25, 0.6, flare=0.1)
    cloud = torch.from_numpy(centred_cloud(x, faces, np.random.default_rng(0), model.config.cloud))[None]
    with torch.no_grad():
        code = model.encode(cloud)
        _, decoded = model.decode(code)
    assert code.shape == (1, model.config.code) and torch.isfinite(decoded).all()
