"""Physics-enforced refinement of a predicted drape.

The prediction is moved out of the body (to the contact thickness, along the skin's
normal) and then relaxed by the cloth simulator itself, from rest: gravity, the fabric's
stretching and bending, contact and friction with the body, self-collision, and still-air
damping, until no vertex moves faster than `rest_speed` (or `max_steps` pass). Damped
implicit dynamics from rest descend the garment's potential (gravity + stretching +
bending) under the simulator's non-penetration constraints, so the result keeps the
network's shape where it is right, ends where the simulator's physics holds, and has no
vertex inside the body. A prediction that crosses itself cannot be untangled by a
collision-preserving relaxation: such crossings are counted and reported."""

from __future__ import annotations

import time

import numpy as np
import torch

from tryon.body.pose import BodyPose
from tryon.drape.dress import DressedGarment, cloth_on_body
from tryon.fabric.base import Fabric

SETTLE_AIR_DAMPING = 4.0  # 1/s, as the simulated drape's settling


def refine_drape(x: np.ndarray, garment: DressedGarment, body: BodyPose, fabric: Fabric, thickness: float = 0.004,
                 friction: float = 0.4, dt: float = 0.01, max_steps: int = 60, rest_speed: float = 0.02,
                 regions: list | None = None, until=None) -> tuple[np.ndarray, dict]:
    """(refined vertices, stats) of a predicted garment `x` on `body`; `regions`: material
    regions beyond the fabric (a print), which the prediction knows nothing of. `until`:
    an observer of the run (`tryon.sim.loop.Observer`) that may end it before the garment
    is at rest, e.g. once what a caller measures of it has settled."""
    from tryon.sim.geometry import count_intersections, push_outside
    from tryon.sim.integrator import ImplicitEulerSolver
    from tryon.sim.loop import SettleTest, run
    from tryon.sim.model import ClothState, Control
    from tryon.sim.obstacles import Obstacle

    t0 = time.perf_counter()
    x0, moved, _ = push_outside(np.asarray(x, np.float64), body.vertices, body.faces, thickness)
    # the model is built on the garment's own drape and the run starts from the prediction:
    # pushing out can leave a triangle degenerate (three vertices on one body edge), which a
    # state may be but a mesh may not
    model = cloth_on_body(garment.cloth_mesh(), fabric, Obstacle("body", body.vertices, body.faces), thickness,
                          friction=friction, regions=regions)
    start = ClothState(torch.from_numpy(x0), torch.zeros(x0.shape, dtype=torch.float64), 0.0)
    crossings, _ = count_intersections(x0, model.faces.numpy(), model.edges.numpy(), body.vertices, body.faces,
                                       model.obstacles.edges)
    at_rest = SettleTest(rest_speed, after=3)
    outcome = run(ImplicitEulerSolver(model), start, dt, until=max_steps, observers=[at_rest, *([until] if until else [])],
                  control=Control(air_damping=SETTLE_AIR_DAMPING))
    return outcome.state.x.numpy(), {"refine_steps": outcome.step, "refine_final_speed": at_rest.speed,
                                     "pushed_out_vertices": int(moved.sum()), "start_self_crossings": int(crossings),
                                     "refine_s": time.perf_counter() - t0}
