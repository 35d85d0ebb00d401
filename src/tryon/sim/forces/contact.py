"""Contact potentials: the proximity penalty and lagged Coulomb friction, each written once.

Both laws act on a contact's four points p_k with weights w_k and normal n (see
`tryon.sim.collision.contacts`). They are written with arithmetic only, so the forward
step evaluates them on numpy arrays and the differentiable step (`tryon.diff.terms`) on
torch tensors, from the same functions.

Penalty (ARCSim's proximity constraints, Narain et al. 2012): on a gap g below the
thickness h, with depth d = h - g,

    E(d) = k d^3 / (6 h),   fn = dE/dd = k d^2 / (2 h),   d2E/dd2 = k d / h,

where k is the collision stiffness times the mean vertex area. Its Hessian
d2E/dd2 (w n)(w n)^T is lumped onto diagonal blocks by a Gershgorin bound:
``|w_k| sum_l |w_l| n n^T`` per point.

Friction (lagged and regularised, as in ARCSim and IPC's lagged friction): the
dissipation potential ``D(v) = c/2 |P vr|^2``, P = I - n n^T, vr = sum_k w_k v_k, with
the coefficient c = mu fn / max(|vt|, slip speed) frozen at the start of the step. Its
force is -dD/dv_k = -c w_k P vr and its velocity Hessian c w_k w_l P, lumped like the
penalty's. A sliding contact feels mu fn against its motion; a resting one creeps at
most at the slip speed.
"""

from __future__ import annotations

from typing import TypeVar

Array = TypeVar("Array")  # a numpy array or a torch tensor

# relative tangential speed (m/s) below which friction turns from Coulomb's constant force
# into viscous sticking: a resting contact creeps at most this fast
FRICTION_SLIP_SPEED = 1e-3


def penalty_energy(depth: Array, h: float, k: float) -> Array:
    """E = k d^3 / (6 h) for penetration depths d = h - gap >= 0."""
    return k * depth**3 / (6 * h)


def penalty_force(depth: Array, h: float, k: float) -> Array:
    """Normal force magnitude fn = dE/dd = k d^2 / (2 h)."""
    return k * depth**2 / (2 * h)


def penalty_stiffness(depth: Array, h: float, k: float) -> Array:
    """d2E/dd2 = k d / h."""
    return k * depth / h


def lumped_weights(w_cloth: Array, scale: Array | None = None) -> Array:
    """Per-point factors [C, 4] of the lumped (Gershgorin) Hessian blocks,
    ``scale |w_k| sum_l |w_l|`` (scale [C, 1], default 1), for weights that are zero at
    obstacle points."""
    a = abs(w_cloth)
    total = a[:, 0:1] + a[:, 1:2] + a[:, 2:3] + a[:, 3:4]
    return a * total if scale is None else scale * a * total


def friction_coefficient(mu: Array, fn: Array, slip_speed: Array) -> Array:
    """c = mu fn / max(|vt|, slip speed); `slip_speed` is that maximum."""
    return mu * fn / slip_speed
