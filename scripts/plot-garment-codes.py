"""docs/images/garment-codes.png: held-out garments through the garment autoencoder, and
codes interpolated between two garment types (front views of the point clouds).
  python scripts/plot-garment-codes.py MODEL.npz DRAPE_DATASET..."""

import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import torch  # noqa: E402

from tryon.learn.train_garment_codes import garment_clouds, load_codes_model  # noqa: E402

model, card = load_codes_model(sys.argv[1])
clouds = garment_clouds(sys.argv[2:], seed=card["training"]["seed"])
test = np.nonzero(clouds.split == "test")[0]
firsts = {g: test[clouds.garment[test] == g][0] for g in dict.fromkeys(clouds.garment[test])}
pairs = [("tshirt", "skirt"), ("trousers", "dress"), ("longsleeve", "trousers")]
pairs = [(a, b) for a, b in pairs if a in firsts and b in firsts]
steps = np.linspace(0.0, 1.0, 5)
fig, ax = plt.subplots(len(pairs) + 1, 5, figsize=(12, 2.8 * (len(pairs) + 1)))


def show(a, p, title, colour="C0"):
    a.scatter(p[:, 0], p[:, 2], s=0.6, c=colour)
    a.set_aspect("equal")
    a.set_xlim(-0.65, 0.65)
    a.set_ylim(-0.6, 0.6)
    a.set_xticks([])
    a.set_yticks([])
    a.set_title(title, fontsize=8)


for a in ax[0, len(firsts):]:
    a.axis("off")
with torch.no_grad():
    for k, (g, row) in enumerate(list(firsts.items())[:5]):
        x = torch.from_numpy(clouds.points[row:row + 1])
        _, rec = model.decode(model.encode(x))
        show(ax[0, k], clouds.points[row], "")
        show(ax[0, k], rec[0].numpy(), f"{g}: held out (blue), decoded (orange)", "C1")
    for i, (a, b) in enumerate(pairs, start=1):
        za, zb = (model.encode(torch.from_numpy(clouds.points[firsts[g]:firsts[g] + 1])) for g in (a, b))
        for k, t in enumerate(steps):
            _, rec = model.decode((1 - t) * za + t * zb)
            show(ax[i, k], rec[0].numpy(), f"{a} -> {b}: {t:.2f}", "C1")
fig.suptitle(f"garment codes: held-out Chamfer {card['test']['chamfer_cm']:.2f} cm", fontsize=10)
fig.tight_layout()
fig.savefig("docs/images/garment-codes.png", dpi=100)
