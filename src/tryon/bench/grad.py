"""`tryon bench grad`: cost of differentiating through contact.

1. Impact-zone backward, QR against full KKT (the ablation of Liang, Lin & Koltun 2019,
   table 1): an N x N cloth pushed into the open pyramid (`pyramid` example, pusher at
   `PUSH_SPEED` so that impacts reach the impact-zone solver every step) is simulated
   forward once; the same backward pass then runs twice, once with each
   `tryon.diff.qp` method, timing only the projection backward passes and summing the
   sizes of the linear systems they solve (QR: m x m triangular per zone, m = active
   independent constraints; KKT: (n + m) square per zone, n = 3 x zone vertices).
2. Full rollout: backward time over (taped) forward time for a 32 x 32 cloth in the
   pyramid scene, and the forward time of the plain simulator for reference.
"""

from __future__ import annotations

import time

import torch

from tryon.diff.qp import STATS
from tryon.diff.rollout import DiffSimulator
from tryon.bench.records import write_records
from tryon.sim.integrator import ImplicitEulerSolver
from tryon.sim.loop import run
from tryon.sim.scene import Scene, example_spec, parse_scene

PUSH_SPEED = 1.5  # m/s; the example's 0.4 m/s leaves nearly every contact to the penalties
PUSH_DEPTH = 0.3  # m the pusher travels


def pushed_pyramid(resolution: int) -> Scene:
    """The `pyramid` example with a faster pusher (module docstring)."""
    spec = example_spec("pyramid", resolution)
    spec["obstacles"][1]["motion"] = {"velocity": [0.0, 0.0, -PUSH_SPEED], "start": 0.0, "stop": PUSH_DEPTH / PUSH_SPEED}
    spec["name"] = f"pyramid-push-{resolution}"
    return parse_scene(spec)


def _loss(traj, weights: torch.Tensor) -> torch.Tensor:
    return (traj.x[-1] * weights).sum() + (traj.v[-1] * weights).sum() * 0.01


def qp_ablation(resolution: int, steps: int) -> list[dict]:
    """One forward rollout, then its backward with the QR and with the KKT method."""
    scene = pushed_pyramid(resolution)
    sim = DiffSimulator(scene.model, scene.dt)
    params = sim.parameters().requires_grad_()
    traj = sim.rollout(steps, params=params)
    weights = torch.randn(traj.x.shape[1:], dtype=traj.x.dtype, generator=torch.Generator().manual_seed(0))
    loss = _loss(traj, weights)
    rows, grads = [], {}
    for method in ("qr", "kkt"):
        sim.ctx.qp_method = method
        STATS.reset()
        tic = time.perf_counter()
        (g,) = torch.autograd.grad(loss, params, retain_graph=method == "qr")
        total = time.perf_counter() - tic
        grads[method] = g
        rows.append({
            "bench": "qp_backward", "grid": resolution, "method": method, "steps": steps,
            "impacts": traj.impacts, "projection_backward_s": STATS.seconds, "rollout_backward_s": total,
            "zones": STATS.zones, "constraints": STATS.constraints, "variables": STATS.variables,
            "system_rows": STATS.system_rows, "system_entries": STATS.system_entries,
            "dependent_constraints": STATS.dependent,
        })
    qr, kkt = rows
    agree = float((grads["qr"] - grads["kkt"]).norm() / grads["kkt"].norm().clamp_min(1e-300))
    for r in rows:
        r["speedup_qr_vs_kkt"] = kkt["projection_backward_s"] / max(qr["projection_backward_s"], 1e-12)
        r["size_ratio_kkt_vs_qr"] = kkt["system_rows"] / max(qr["system_rows"], 1)
        r["gradient_difference"] = agree
    return rows


def rollout_ratio(resolution: int, steps: int) -> dict:
    """Backward over forward time of a whole rollout with contact."""
    scene = pushed_pyramid(resolution)
    plain = ImplicitEulerSolver(scene.model, scene.options)
    plain_s = run(plain, scene.model.initial_state(), scene.dt, until=steps).wall_s
    sim = DiffSimulator(scene.model, scene.dt)
    params = sim.parameters().requires_grad_()
    v0 = torch.zeros(scene.model.num_vertices, 3, dtype=torch.float64, requires_grad=True)
    tic = time.perf_counter()
    traj = sim.rollout(steps, params=params, v0=v0)
    forward_s = time.perf_counter() - tic
    weights = torch.randn(traj.x.shape[1:], dtype=traj.x.dtype, generator=torch.Generator().manual_seed(1))
    loss = _loss(traj, weights)
    tic = time.perf_counter()
    loss.backward()
    backward_s = time.perf_counter() - tic
    return {
        "bench": "rollout", "grid": resolution, "steps": steps, "impacts": traj.impacts,
        "forward_s": forward_s, "backward_s": backward_s, "backward_over_forward": backward_s / forward_s,
        "plain_forward_s": plain_s, "backward_over_plain_forward": backward_s / plain_s, "target_ratio": 3.0,
    }


def _print_table(records: list[dict]) -> None:
    print("impact-zone backward: QR of W^-1/2 G^T against the full (n+m) KKT system")
    print(f"{'grid':>6s} {'steps':>5s} {'impacts':>7s} {'zones':>6s} {'QR s':>8s} {'KKT s':>8s} {'speedup':>8s} "
          f"{'QR rows':>8s} {'KKT rows':>9s} {'smaller':>8s} {'dep':>4s}")
    for qr, kkt in zip(*(iter([r for r in records if r["bench"] == "qp_backward"]),) * 2):
        print(f"{qr['grid']:>4d}^2 {qr['steps']:5d} {qr['impacts']:7d} {qr['zones']:6d} {qr['projection_backward_s']:8.3f} "
              f"{kkt['projection_backward_s']:8.3f} {qr['speedup_qr_vs_kkt']:7.1f}x {qr['system_rows']:8d} "
              f"{kkt['system_rows']:9d} {qr['size_ratio_kkt_vs_qr']:7.1f}x {qr['dependent_constraints']:4d}")
    for r in (r for r in records if r["bench"] == "rollout"):
        print(f"rollout {r['grid']}x{r['grid']}, {r['steps']} steps, {r['impacts']} impacts: forward {r['forward_s']:.2f} s "
              f"(plain simulator {r['plain_forward_s']:.2f} s), backward {r['backward_s']:.2f} s, "
              f"backward/forward {r['backward_over_forward']:.2f}x (target < 3x)")


def run_grad_bench(json_path: str, quick: bool = False) -> list[dict]:
    """Run the benchmark (module docstring), print a table and write the records as JSON."""
    grids, steps, rollout = ([8, 12], 8, (12, 8)) if quick else ([16, 32, 64], 25, (32, 30))
    torch.set_num_threads(1)
    records: list[dict] = []
    for res in grids:
        records += qp_ablation(res, steps)
    records.append(rollout_ratio(*rollout))
    _print_table(records)
    write_records(json_path, records, threads=torch.get_num_threads(), quick=quick)
    return records
