"""Gradients of rollout losses against central finite differences, for every kind of
input, on small scenes without contact (hanging cloth), with impacts resolved by impact
zones, and with proximity contact and friction (cloth resting on a sphere)."""

from __future__ import annotations

import pytest
import torch

from tryon.diff import Controls, DiffSimulator
from tryon.errors import TryonError
from tryon.sim.scene import example_scene

F64 = torch.float64


def _setup(name: str, res: int, pre_steps: int, push: float = 0.0):
    """Scene, simulator and a start state: the rest shape with 2 mm of seeded out-of-plane
    noise, simulated for `pre_steps` steps, plus `push` m/s downwards. The noise keeps
    every face strained: at exactly zero strain (a rest or rigidly moved face) the
    membrane force has kinks (max(G, 0) in its Hessian, |G_uv| in the Wang 2011 lookup)
    where finite differences and derivatives legitimately disagree."""
    scene = example_scene(name, resolution=res, dt=0.01)
    sim = DiffSimulator(scene.model, scene.dt)
    x_init = scene.model.initial_state().x.clone()
    x_init[:, 2] += 2e-3 * torch.randn(len(x_init), dtype=F64, generator=torch.Generator().manual_seed(17))
    with torch.no_grad():
        pre = sim.rollout(pre_steps, x0=x_init)
    v0 = pre.v[-1].clone()
    v0[:, 2] -= push
    return scene, sim, pre.x[-1].clone(), v0


def _check(loss, base: dict, name: str, direction: torch.Tensor, h: float, rel: float) -> tuple[float, float]:
    """Directional derivative of loss(**inputs) along `direction` for input `name`:
    autograd against central differences."""
    leaves = {k: v.clone().requires_grad_(k == name) for k, v in base.items()}
    loss(leaves).backward()
    analytic = float((leaves[name].grad * direction).sum())
    with torch.no_grad():
        plus = dict(base, **{name: base[name] + h * direction})
        minus = dict(base, **{name: base[name] - h * direction})
        fd = (float(loss(plus)) - float(loss(minus))) / (2 * h)
    assert analytic == pytest.approx(fd, rel=rel, abs=1e-9), f"{name}: autograd {analytic:.8g} vs finite differences {fd:.8g}"
    return analytic, fd


def _weights(steps: int, n: int, seed: int) -> torch.Tensor:
    return torch.randn(steps + 1, n, 3, dtype=F64, generator=torch.Generator().manual_seed(seed))


@pytest.fixture(scope="module")
def hanging():
    scene, sim, x0, v0 = _setup("hanging", 6, 10)
    steps, n = 5, scene.model.num_vertices
    W = _weights(steps, n, 0)
    fv = torch.tensor([0, n // 2, n - 1])
    handles = x0[sim._pinned][None] + torch.linspace(0.0, 0.02, steps, dtype=F64)[:, None, None]
    base = {"params": sim.parameters(), "x0": x0, "v0": v0, "forces": torch.full((steps, 3, 3), 0.01, dtype=F64),
            "wind": torch.tensor([[1.0, 0.5, 0.2]], dtype=F64).repeat(steps, 1), "handles": handles}

    def loss(inp):
        ctrl = Controls(forces=inp["forces"], force_vertices=fv, wind=inp["wind"], handles=inp["handles"])
        tr = sim.rollout(steps, params=inp["params"], x0=inp["x0"], v0=inp["v0"], controls=ctrl)
        assert tr.impacts == 0
        return (tr.x * W).sum() + 0.1 * (tr.v * W).sum()

    return loss, base


@pytest.mark.parametrize("part", ["density", "stretching", "bending"])
def test_fabric_parameter_gradients_without_contact(hanging, part):
    loss, base = hanging
    p = base["params"]
    d = torch.zeros_like(p)
    span = {"density": slice(0, 1), "stretching": slice(1, 25), "bending": slice(25, 40)}[part]
    d[span] = p[span] * torch.linspace(0.5, 1.5, span.stop - span.start, dtype=F64)
    # bending moves this loss very little: a larger step lifts it above the solver's noise
    _check(loss, base, "params", d, 5e-2 if part == "bending" else 1e-4, 2e-3)


@pytest.mark.parametrize("name,scale,rel", [("x0", 1e-3, 2e-3), ("v0", 0.1, 5e-3), ("forces", 0.05, 1e-3),
                                            ("wind", 1.0, 1e-2), ("handles", 1e-3, 2e-3)])
def test_state_and_control_gradients_without_contact(hanging, name, scale, rel):
    loss, base = hanging
    d = torch.randn(base[name].shape, dtype=F64, generator=torch.Generator().manual_seed(1)) * scale
    _check(loss, base, name, d, 1e-3, rel)


def _translation(x: torch.Tensor, seed: int) -> torch.Tensor:
    """A smooth direction field (rotation about z plus translation): random per-vertex
    directions make finite differences through stiff contacts meaningless."""
    g = torch.Generator().manual_seed(seed)
    t = torch.randn(3, dtype=F64, generator=g) * 0.01
    c = x.mean(0)
    rot = torch.stack([-(x[:, 1] - c[1]), x[:, 0] - c[0], torch.zeros(len(x), dtype=F64)], 1) * 0.02
    return t[None] + rot


@pytest.fixture(scope="module")
def impacts():
    """Cloth thrown onto a sphere at 4 m/s: many impacts per step resolved by impact zones."""
    scene, sim, x0, v0 = _setup("sphere-drop", 8, 1, push=4.0)
    steps, n = 3, scene.model.num_vertices
    W = _weights(steps, n, 2)
    fv = torch.arange(0, n, 7)
    base = {"params": sim.parameters(), "x0": x0, "v0": v0, "forces": torch.zeros(steps, len(fv), 3, dtype=F64),
            "wind": torch.tensor([0.5, -0.3, 0.0], dtype=F64)}
    stats = {}

    def loss(inp):
        ctrl = Controls(forces=inp["forces"], force_vertices=fv, wind=inp["wind"])
        tr = sim.rollout(steps, params=inp["params"], x0=inp["x0"], v0=inp["v0"], controls=ctrl)
        stats["impacts"] = tr.impacts
        return (tr.x * W).sum() + 0.1 * (tr.v * W).sum()

    return loss, base, stats


@pytest.mark.parametrize("name", ["params", "x0", "v0", "forces", "wind"])
def test_gradients_through_impact_zones(impacts, name):
    loss, base, stats = impacts
    g = torch.Generator().manual_seed(3)
    if name == "params":
        d = base["params"] * torch.rand(40, dtype=F64, generator=g)
    elif name == "x0":
        d = _translation(base["x0"], 4)
    else:
        d = torch.randn(base[name].shape, dtype=F64, generator=g) * 0.1
    _check(loss, base, name, d, 1e-4, 1e-2 if name == "x0" else 1e-3)
    assert stats["impacts"] > 20


@pytest.fixture(scope="module")
def resting():
    """Cloth settling on a sphere: proximity penalties and Coulomb friction in the solve."""
    scene, sim, x0, v0 = _setup("sphere-drop", 8, 25)
    steps, n = 6, scene.model.num_vertices
    W = _weights(steps, n, 5)
    base = {"params": sim.parameters(), "x0": x0, "v0": v0, "forces": torch.zeros(steps, n, 3, dtype=F64)}

    def loss(inp, friction="exact"):
        sim.ctx.friction_gradient = friction
        tr = sim.rollout(steps, params=inp["params"], x0=inp["x0"], v0=inp["v0"], controls=Controls(forces=inp["forces"]))
        return (tr.x * W).sum() + 0.1 * (tr.v * W).sum()

    return loss, base


@pytest.mark.parametrize("name", ["params", "v0", "forces"])
def test_gradients_through_contact_and_friction(resting, name):
    loss, base = resting
    g = torch.Generator().manual_seed(6)
    d = base["params"] * torch.rand(40, dtype=F64, generator=g) if name == "params" else torch.randn(base[name].shape, dtype=F64, generator=g) * 0.1
    _check(loss, base, name, d, 1e-4, 3e-3)


def test_constant_friction_gradient_is_an_approximation(resting):
    """Holding friction's coefficient constant changes the gradient measurably: the exact
    mode is the one that matches finite differences (checked above)."""
    loss, base = resting
    grads = {}
    for mode in ("exact", "constant"):
        v0 = base["v0"].clone().requires_grad_()
        loss(dict(base, v0=v0), friction=mode).backward()
        grads[mode] = v0.grad
    rel = float((grads["exact"] - grads["constant"]).norm() / grads["exact"].norm())
    assert rel > 1e-3


def test_checkpointed_rollout_gives_the_same_gradients():
    scene, sim, x0, v0 = _setup("sphere-drop", 6, 1, push=3.0)
    W = _weights(6, scene.model.num_vertices, 8)
    grads, values = [], []
    for every in (None, 2):
        p = sim.parameters().requires_grad_()
        v = v0.clone().requires_grad_()
        tr = sim.rollout(6, params=p, x0=x0, v0=v, checkpoint_every=every)
        loss = (tr.x * W).sum()
        loss.backward()
        values.append(float(loss.detach()))
        grads.append((p.grad.clone(), v.grad.clone()))
    assert values[0] == pytest.approx(values[1], rel=1e-12)
    torch.testing.assert_close(grads[0][0], grads[1][0], rtol=1e-9, atol=1e-12)
    torch.testing.assert_close(grads[0][1], grads[1][1], rtol=1e-9, atol=1e-12)


def test_policy_parameters_get_gradients():
    """Forces from a small network of the state: its weights' gradient against finite
    differences."""
    scene, sim, x0, v0 = _setup("hanging", 5, 10)
    n = scene.model.num_vertices
    corners = torch.tensor([0, n - 1])
    torch.manual_seed(0)
    net = torch.nn.Sequential(torch.nn.Linear(6, 8), torch.nn.Tanh(), torch.nn.Linear(8, 6)).double()

    def policy(k, x, v):
        return 0.05 * net(torch.cat([x[corners].mean(0), v[corners].mean(0)])).reshape(2, 3)

    W = _weights(4, n, 9)

    def loss():
        tr = sim.rollout(4, x0=x0, v0=v0, controls=Controls(policy=policy, force_vertices=corners))
        return (tr.x * W).sum()

    loss().backward()
    weight = net[2].weight
    d = torch.randn(weight.shape, dtype=F64, generator=torch.Generator().manual_seed(2))
    analytic = float((weight.grad * d).sum())
    h = 1e-4
    with torch.no_grad():
        weight += h * d
        lp = float(loss())
        weight -= 2 * h * d
        lm = float(loss())
        weight += h * d
    assert analytic == pytest.approx((lp - lm) / (2 * h), rel=2e-3)


def test_bad_inputs_raise_clear_errors():
    scene = example_scene("hanging", resolution=4, dt=0.01)
    sim = DiffSimulator(scene.model, scene.dt)
    n = scene.model.num_vertices
    with pytest.raises(TryonError, match="x0 must have shape"):
        sim.rollout(2, x0=torch.zeros(n + 1, 3, dtype=F64))
    with pytest.raises(TryonError, match="controls.forces"):
        sim.rollout(3, controls=Controls(forces=torch.zeros(2, n, 3, dtype=F64)))
    with pytest.raises(TryonError, match="params must have shape"):
        sim.rollout(2, params=torch.zeros(3, dtype=F64))
    with pytest.raises(TryonError, match="qp_method"):
        DiffSimulator(scene.model, scene.dt, qp_method="dense")
