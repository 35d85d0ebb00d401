"""docs/images/fabric-classes.png: the sensitivity tests' responses with the bin edges, and
the measured fabrics on the 54 classes (python scripts/plot-fabric-classes.py)."""

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from tryon.fabric import load_fabric  # noqa: E402
from tryon.perceive.fabric_classes import default_classes  # noqa: E402
from tryon.perceive.fabric_sensitivity import Response, smoothed_response  # noqa: E402

classes = default_classes()
responses = classes.provenance["responses"]
fig, ax = plt.subplots(1, 3, figsize=(15, 4.2))
tests = (("stretching", classes.stretch_edges, "hangs below its length, mm"),
         ("bending", classes.bend_edges, "100 (1 - drape coefficient), %"))
for k, (axis, edges, unit) in enumerate(tests):
    r = Response(**responses[axis])
    s, d = smoothed_response(r)
    ax[k].plot(r.log10_stiffness, r.deformation, "o", label="simulated")
    ax[k].plot(s, d, "-", label="power-law fit")
    for e in edges:
        ax[k].axvline(e, color="0.7", lw=0.8)
    ax[k].set_xlabel(f"log10 {axis} stiffness")
    ax[k].set_ylabel(unit)
    ax[k].set_title(f"{axis}: {len(edges) - 1} bins at equal deformation steps")
    ax[k].legend()
grid = ax[2]
for e in classes.stretch_edges:
    grid.axvline(e, color="0.8", lw=0.8)
for e in classes.bend_edges:
    grid.axhline(e, color="0.8", lw=0.8)
for name, c in classes.preset_classes().items():
    s, b = classes.position(load_fabric(name))
    grid.plot(s, b, "o")
    grid.annotate(f"{name} ({classes.name(c)})", (s, b), fontsize=7, xytext=(3, 3), textcoords="offset points")
grid.set_xlabel("log10 stretching stiffness (N/m)")
grid.set_ylabel("log10 bending stiffness (N m)")
grid.set_title("the 54 classes and the measured fabrics")
fig.tight_layout()
fig.savefig("docs/images/fabric-classes.png", dpi=110)
