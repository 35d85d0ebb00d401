"""A posted body kept for its fits: the fitted body (`tryon.body.fit.BodyFit`) written
once when it is posted, so no worker fits it again. The mesh is left out (Anny rebuilds it
from the shape parameters in milliseconds); the file is a few kB."""

from __future__ import annotations

import dataclasses
import pickle
from pathlib import Path

from tryon.body.fit import BodyFit


def save_body(fit: BodyFit, path: Path) -> None:
    from tryon.io.atomic import atomic_write

    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_write(path, "wb") as fh:
        pickle.dump(dataclasses.replace(fit, shape=None), fh, protocol=pickle.HIGHEST_PROTOCOL)


def load_body(path: str | Path) -> BodyFit:
    """The body saved at `path` (a file this service wrote under its --data)."""
    from tryon.body.anny_model import body_model

    with open(path, "rb") as fh:
        fit = pickle.load(fh)  # noqa: S301 - the service's own file, never an upload
    import torch

    with torch.no_grad():
        shape = body_model().rest_shape(fit.params).detached()
    return dataclasses.replace(fit, shape=shape)


def quick_body(request: dict):
    """The quick fit (`tryon.body.amortised.quick_fit`, on one torch thread) of a shopper's
    numbers: a `BodyFit`."""
    from tryon.body.amortised import quick_fit
    from tryon.body.fit import Measurements
    from tryon.io.threads import one_torch_thread

    with one_torch_thread():
        return quick_fit(Measurements(**request))


def fit_and_save_body(request: dict, path: str) -> dict:
    """Fit the body of `request` (a shopper's numbers: `tryon.body.fit.Measurements`'
    fields) with the quick fit, save it at `path` and return what the API answers of it.
    Run by an answer worker (no fit holds the server's own process), or in a thread."""
    fit = quick_body(request)
    save_body(fit, Path(path))
    return {"measurements": {k: round(v, 2) for k, v in fit.achieved.items()}, "warnings": list(fit.notes),
            "fit_s": round(fit.wall_s, 3)}
