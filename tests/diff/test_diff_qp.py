"""Backward pass of the impact-zone projection (QR of the active constraints, full KKT)
and the time-of-impact derivative, against central finite differences."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from tryon.diff.geometry import impact_time, triple
from tryon.diff.qp import STATS, Projection, ProjectionFn, projection_backward
from tryon.sim.collision.qp import solve_projection

TARGET = 1e-3


def _problem(seed: int):
    """Eight free vertices and two pinned ones coupled by six four-point constraints with
    random weights (summing to zero) and normals; about half of them start violated."""
    rng = np.random.default_rng(seed)
    n_v = 10
    x = rng.normal(size=(n_v, 3)) * 0.05
    mass = rng.uniform(0.5, 2.0, n_v)
    free = np.ones(n_v, bool)
    free[[8, 9]] = False
    idx = np.array([[0, 1, 2, 3], [2, 3, 4, 5], [4, 5, 6, 7], [6, 7, 8, 0], [1, 3, 5, 9], [0, 4, 6, 2]])
    w = rng.uniform(0.2, 1.0, (6, 4)) * np.array([1.0, 1.0, -1.0, -1.0])
    w[:, 2:] *= -w[:, :2].sum(1, keepdims=True) / w[:, 2:].sum(1, keepdims=True)
    n = rng.normal(size=(6, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    return x, mass, free, idx, w, n


def _solve(x, mass, free, idx, w, n) -> tuple[np.ndarray, np.ndarray]:
    inv_mass = np.where(free, 1.0 / mass, 0.0)
    qp = solve_projection(x, inv_mass, idx, w, n, np.zeros((0, 3)), TARGET, None, 1e-14)
    return qp.z, qp.lam


@pytest.mark.parametrize("method", ["qr", "kkt"])
def test_projection_gradients_match_finite_differences(method):
    rng = np.random.default_rng(3)
    x, mass, free, idx, w, n = _problem(3)
    z, lam = _solve(x, mass, free, idx, w, n)
    active = lam > 1e-8
    assert 2 <= active.sum() < len(lam), "the test problem must have active and inactive constraints"
    gz = rng.normal(size=z.shape)
    proj = Projection(idx, z, lam, free, np.zeros((0, 3)), TARGET, method)
    g_x, g_m, g_w, g_n = projection_backward(proj, x, mass, w, n, gz)

    def loss(xx=x, mm=mass, ww=w, nn=n):
        zz, _ = _solve(xx, mm, free, idx, ww, nn)
        return float(np.sum(gz * zz))

    h = 1e-6
    for name, base, grad in (("x", x, g_x), ("mass", mass, g_m), ("w", w, g_w), ("n", n, g_n)):
        d = rng.normal(size=base.shape)
        fd = (loss(**{_arg(name): base + h * d}) - loss(**{_arg(name): base - h * d})) / (2 * h)
        an = float(np.sum(grad * d))
        assert an == pytest.approx(fd, rel=1e-4, abs=1e-7), f"d/d{name}: analytic {an} vs finite differences {fd}"


def _arg(name: str) -> str:
    return {"x": "xx", "mass": "mm", "w": "ww", "n": "nn"}[name]


def _dependent_problem(seed: int):
    """Three active constraints on the same four vertices and normal, the third the mean
    of the other two (rank 2), with positive multipliers on all three: x is built from
    the KKT conditions so that z is its projection."""
    rng = np.random.default_rng(seed)
    mass = rng.uniform(0.5, 2.0, 4)
    free = np.ones(4, bool)
    idx = np.tile(np.arange(4), (3, 1))
    n = np.tile([[0.0, 0.0, 1.0]], (3, 1))
    w = np.array([[1.0, -0.5, -0.3, -0.2], [0.4, 0.6, -1.0, 0.0], [0.0, 0.0, 0.0, 0.0]])
    w[2] = 0.5 * (w[0] + w[1])
    G = np.zeros((3, 12))
    G[:, 2::3] = w
    z0 = rng.normal(size=12) * 0.05
    Minv = np.repeat(1.0 / mass, 3)
    Ga = G[:2]
    r = TARGET - Ga @ z0
    z = z0 + Minv * (Ga.T @ np.linalg.solve((Ga * Minv) @ Ga.T, r))
    lam = np.array([1.0, 2.0, 0.5]) * 1e-2
    x = z - Minv * (G.T @ lam)
    return x.reshape(4, 3), mass, free, idx, w, n, z.reshape(4, 3), lam


def test_dependent_constraints_are_handled_and_methods_agree():
    """Linearly dependent active constraints: the QR method drops one (moving its
    multiplier onto the others) and still gives the gradient of the unique solution."""
    rng = np.random.default_rng(5)
    x, mass, free, idx, w, n, z, lam = _dependent_problem(5)
    z_check, _ = _solve(x, mass, free, idx, w, n)
    np.testing.assert_allclose(z_check, z, atol=1e-9)
    gz = rng.normal(size=z.shape)
    out = {}
    for method in ("qr", "kkt"):
        STATS.reset()
        out[method] = projection_backward(Projection(idx, z, lam, free, np.zeros((0, 3)), TARGET, method), x, mass, w, n, gz)
        assert STATS.dependent == 1
    np.testing.assert_allclose(out["qr"][0], out["kkt"][0], rtol=1e-8, atol=1e-10)
    np.testing.assert_allclose(out["qr"][1], out["kkt"][1], rtol=1e-8, atol=1e-10)
    h = 1e-6
    for k, base in ((0, x), (1, mass)):
        d = rng.normal(size=base.shape)
        args = [x, mass]
        plus, minus = list(args), list(args)
        plus[k], minus[k] = base + h * d, base - h * d
        fd = (np.sum(gz * _solve(*plus, free, idx, w, n)[0]) - np.sum(gz * _solve(*minus, free, idx, w, n)[0])) / (2 * h)
        assert float(np.sum(out["qr"][k] * d)) == pytest.approx(fd, rel=1e-5, abs=1e-9)


def test_qr_system_is_smaller_than_kkt():
    rng = np.random.default_rng(7)
    x, mass, free, idx, w, n = _problem(3)
    z, lam = _solve(x, mass, free, idx, w, n)
    rows = {}
    for method in ("qr", "kkt"):
        STATS.reset()
        projection_backward(Projection(idx, z, lam, free, np.zeros((0, 3)), TARGET, method), x, mass, w, n, rng.normal(size=z.shape))
        rows[method] = STATS.system_rows
    assert rows["qr"] == int((lam > 1e-8).sum())
    assert rows["kkt"] > 3 * rows["qr"]


def test_projection_fn_is_an_autograd_function():
    x, mass, free, idx, w, n = _problem(3)
    z, lam = _solve(x, mass, free, idx, w, n)
    proj = Projection(idx, z, lam, free, np.zeros((0, 3)), TARGET, "qr")
    xt = torch.from_numpy(x).requires_grad_()
    out = ProjectionFn.apply(xt, torch.from_numpy(mass), torch.from_numpy(w), torch.from_numpy(n), proj)
    assert torch.allclose(out, torch.from_numpy(z))
    out.pow(2).sum().backward()
    g_ref = projection_backward(proj, x, mass, w, n, 2 * z)[0]
    np.testing.assert_allclose(xt.grad.numpy(), g_ref)


def test_time_of_impact_derivative_matches_the_cubic_root():
    """t* solves c(t) = 0 for the coplanarity cubic; its implicit derivative against a
    root found afresh (bisection) for perturbed end positions."""
    rng = np.random.default_rng(11)
    X0 = np.array([[[0.1, 0.2, 0.3], [0.0, 0.0, 0.0], [1.0, 0.0, 0.05], [0.0, 1.0, -0.05]]])
    X1 = X0.copy()
    X1[0, 0, 2] = -0.4
    X1[0, 1:] += rng.normal(size=(3, 3)) * 0.02

    def root(x1: np.ndarray) -> float:
        def c(t):
            P = torch.from_numpy(X0 + t * (x1 - X0))
            return float(triple(P[:, 1] - P[:, 0], P[:, 2] - P[:, 0], P[:, 3] - P[:, 0])[0])

        lo, hi = 0.0, 1.0
        assert c(lo) * c(hi) < 0
        for _ in range(200):
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if c(lo) * c(mid) > 0 else (lo, mid)
        return 0.5 * (lo + hi)

    t_ref = np.array([root(X1)])
    x1 = torch.from_numpy(X1).requires_grad_()
    t = impact_time(torch.from_numpy(X0), x1, t_ref)
    assert float(t[0].detach()) == pytest.approx(t_ref[0], abs=1e-12)
    t.sum().backward()
    d = rng.normal(size=X1.shape)
    h = 1e-6
    fd = (root(X1 + h * d) - root(X1 - h * d)) / (2 * h)
    assert float((x1.grad.numpy() * d).sum()) == pytest.approx(fd, rel=1e-5)
