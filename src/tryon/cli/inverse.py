"""Commands of the differentiable simulator: `tryon fit-fabric` and `tryon control`."""

from __future__ import annotations

import argparse
import json


def _small_problem_threads() -> None:
    """These runs do many small tensor operations per step: torch's thread pool only adds
    contention (10x slower on a busy 2-core machine)."""
    import torch

    torch.set_num_threads(1)


def _cmd_fit_fabric(args: argparse.Namespace) -> int:
    from tryon.errors import TryonError

    _small_problem_threads()
    if args.make_observed:
        from tryon.diff.observed import make_observed, save_observed

        preset, out = args.make_observed
        obs = make_observed(preset, resolution=args.resolution, duration=args.duration, progress=not args.quiet)
        save_observed(out, obs)
        print(f"wrote {out}: {obs.num_frames} frames of {obs.positions.shape[1]} vertices, fabric {obs.fabric}")
        return 0
    if not args.observed or not args.out:
        raise TryonError("fit-fabric needs OBSERVED.npz and --out DIR (or --make-observed PRESET OUT.npz)")
    from tryon.diff.fit import run_fit_fabric

    from tryon.render.sim_pictures import sequence_comparison_png

    report = run_fit_fabric(args.observed, args.out, scene=args.scene, truth=args.truth, method=args.method,
                            progress=not args.quiet, force=args.force, comparison_picture=sequence_comparison_png)
    keys = ["simulation_error", "simulation_error_at_truth", "dt", "handles", "simulations", "simulated_steps", "wall_s",
            "density_error", "stretching_error", "bending_error"]
    print(json.dumps({k: report[k] for k in keys if k in report}, indent=2))
    print(f"wrote {args.out}/fabric.json, loss_curve.png, observed_vs_fit.png, report.json")
    return 0


def _cmd_control(args: argparse.Namespace) -> int:
    from tryon.diff.control import MODES, VARIANTS, run_control
    from tryon.render.sim_pictures import trajectory_gif

    _small_problem_threads()
    modes = MODES if args.mode == "all" else (args.mode,)
    variants = VARIANTS if args.variant == "both" else (args.variant,)
    report = run_control(args.example, args.out, modes=modes, variants=variants, iterations=args.iterations,
                         resolution=args.resolution, progress=not args.quiet, force=args.force,
                         preview=trajectory_gif)
    print(f"{'variant':8s} {'mode':11s} {'distance/size':>13s} {'inside':>6s} {'samples':>7s} {'wall s':>7s}")
    for r in report["results"]:
        print(f"{r['variant']:8s} {r['mode']:11s} {r['final_distance_over_size']:13.3f} {str(r['landed_inside']):>6s} "
              f"{r['samples']:7d} {r['wall_s']:7.1f}")
    print(f"wrote {args.out}/report.json and preview GIFs")
    return 0


def add_commands(sub: argparse._SubParsersAction) -> None:
    """Register this package's subcommands on the `tryon` parser."""
    f = sub.add_parser("fit-fabric", help="estimate a fabric from an observed sequence (differentiable simulation)")
    f.add_argument("observed", nargs="?", help="observed .npz (positions, faces, uv, pinned, frame_time, gravity, wind_*)")
    f.add_argument("--scene", help="scene YAML the sequence was recorded in (optional for hanging-in-wind files)")
    f.add_argument("--out", help="output folder: fabric.json, loss_curve.png, observed_vs_fit.png, report.json")
    f.add_argument("--truth", help="preset the sequence was made with: adds parameter errors to the report")
    f.add_argument("--method", choices=["gauss-newton", "gradient", "finite-difference", "physical"],
                   default="gauss-newton")
    f.add_argument("--make-observed", nargs=2, metavar=("PRESET", "OUT.npz"),
                   help="instead of fitting, simulate the hanging-in-wind scene with PRESET and write OUT.npz")
    f.add_argument("--resolution", type=int, default=8, help="grid resolution for --make-observed")
    f.add_argument("--duration", type=float, default=1.0, help="seconds simulated for --make-observed")
    f.add_argument("--quiet", action="store_true")
    f.add_argument("--force", action="store_true", help="replace an existing --out folder tryon did not write")
    f.add_argument("--allow-large", action="store_true",
                   help="lift the limits on steps, frames, vertices, memory and file sizes (tryon.limits)")
    f.set_defaults(func=_cmd_fit_fabric)

    c = sub.add_parser("control", help="steer cloth by optimising forces through the differentiable simulator")
    c.add_argument("--example", required=True, choices=["basket"])
    c.add_argument("--out", default="control-basket", help="output folder (report.json, preview GIFs)")
    c.add_argument("--mode", choices=["direct", "policy", "point-mass", "sampling", "all"], default="all")
    c.add_argument("--variant", choices=["flat", "sloped", "both"], default="both")
    c.add_argument("--iterations", type=int, default=30, help="optimisation steps (one simulation each)")
    c.add_argument("--resolution", type=int, default=5, help="cloth grid resolution")
    c.add_argument("--quiet", action="store_true")
    c.add_argument("--force", action="store_true", help="replace an existing --out folder tryon did not write")
    c.set_defaults(func=_cmd_control)
