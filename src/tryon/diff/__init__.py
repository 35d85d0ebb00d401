"""Differentiable cloth simulation through contact (Liang, Lin & Koltun 2019) and the
inverse problems built on it (docs/DIFF.md).

* `DiffSimulator.rollout`: a trajectory whose gradients reach fabric parameters, the
  initial state, per-step forces (or a policy), wind and handle motion; implicit solve
  differentiated by one adjoint solve with the forward factorisation, impact zones by QR
  of the active constraints (`tryon.diff.qp`), checkpointed segments for long rollouts.
* `tryon.diff.observed` / `tryon.diff.fit`: observed sequences and fabric estimation
  (`tryon fit-fabric`).
* `tryon.diff.control`: motion control, cloth into a basket (`tryon control`).
* `tryon bench grad` (in `tryon.bench.grad`) measures the cost of differentiating.
"""

from tryon.diff.control import BasketTask, run_control
from tryon.diff.fit import FabricEstimator, fit_fabric, parameter_errors, run_fit_fabric
from tryon.diff.observed import Observation, load_observed, make_observed, save_observed
from tryon.diff.rollout import Controls, DiffSimulator, Trajectory

__all__ = [
    "BasketTask",
    "Controls",
    "DiffSimulator",
    "FabricEstimator",
    "Observation",
    "Trajectory",
    "fit_fabric",
    "load_observed",
    "make_observed",
    "parameter_errors",
    "run_control",
    "run_fit_fabric",
    "save_observed",
]
