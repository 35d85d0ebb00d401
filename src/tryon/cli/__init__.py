"""The `tryon` command. Thin: it parses arguments and calls the packages."""

from __future__ import annotations

import argparse
import math
import os
import sys
from pathlib import Path

from tryon.errors import TryonError
from tryon.limits import ALLOW_LARGE_ENV
from tryon.io.atomic import check_output_dir
from tryon.io.json_safe import dumps_json

DEFAULT_GRIDS = [16, 32, 64, 128]


def _cmd_simulate(args: argparse.Namespace) -> int:
    from tryon.render.sim_pictures import render_state_png
    from tryon.sim.runner import run_scene
    from tryon.sim.scene import example_scene, load_scene, parse_scene, example_spec

    if args.example and args.scene:
        raise TryonError("give either a SCENE.yaml or --example NAME, not both")
    _check_positive(args, "dt", "duration")
    if args.out is not None and not args.dump:
        check_output_dir(args.out, force=args.force)
    if args.example:
        if args.dump:
            import yaml

            print(yaml.safe_dump(example_spec(args.example, args.resolution), sort_keys=False))
            return 0
        scene = example_scene(args.example, args.resolution, dt=args.dt, duration=args.duration, fabric=args.fabric)
    elif args.scene:
        scene = load_scene(args.scene)
        if args.dt is not None or args.duration is not None or args.fabric:
            spec = dict(scene.spec)
            spec.update({k: v for k, v in (("dt", args.dt), ("duration", args.duration)) if v is not None})
            if args.fabric:
                spec["cloth"] = dict(spec["cloth"], fabric=args.fabric)
            scene = parse_scene(spec, Path(args.scene).parent, scene.name)
    else:
        raise TryonError("give a SCENE.yaml or --example NAME (hanging, sphere-drop, table, pyramid)")
    if args.linear_solver:
        scene.options.linear_solver = args.linear_solver
    out = check_output_dir(args.out or f"out/{scene.name}", force=args.force)
    if args.parallel == "time":
        from tryon.parallel import run_scene_time_parallel

        result = run_scene_time_parallel(scene, out, progress=not args.quiet, resume=args.resume,
                                         write_objs=not args.no_obj, options=_parallel_options(args), force=args.force,
                                         picture=render_state_png)
    else:
        result = run_scene(scene, out, progress=not args.quiet, resume=args.resume, write_objs=not args.no_obj,
                           force=args.force, picture=render_state_png)
    s = result.summary
    print(
        f"{scene.name}: {s['steps']} steps in {s['wall_s']:.1f} s ({s['s_per_step'] * 1000:.1f} ms/step), "
        f"max strain {s['max_strain'] * 100:.1f} %, intersections {s['intersections']}, "
        f"min obstacle distance {s['min_obstacle_distance'] * 1000:.2f} mm -> {out}"
    )
    return 0


def _check_positive(args: argparse.Namespace, *names: str) -> None:
    for name in names:
        value = getattr(args, name)
        if value is not None and not (value > 0 and value < float("inf")):
            raise TryonError(f"--{name.replace('_', '-')} must be a positive number of seconds, got {value}")


def _force_arg(p: argparse.ArgumentParser) -> None:
    p.add_argument("--force", action="store_true",
                   help="replace an existing --out folder even if tryon did not write it (never /, ~, . or its parents)")
    _allow_large_arg(p)


def _allow_large_arg(p: argparse.ArgumentParser) -> None:
    p.add_argument("--allow-large", action="store_true",
                   help="lift the limits on steps, frames, vertices, memory and file sizes (tryon.limits)")


def _measurements(args: argparse.Namespace):
    from tryon.body.fit import Measurements

    from tryon.body.fit import TAPE_RANGE_CM

    extra = {f"{k}_cm": getattr(args, f"{k}_cm", None) for k in TAPE_RANGE_CM}
    return Measurements(height_cm=args.height_cm, gender=args.gender, weight_kg=args.weight_kg, bmi=args.bmi, age=args.age,
                        chest_cm=args.chest_cm, waist_cm=args.waist_cm, hip_cm=args.hip_cm, **extra)


def _person(args: argparse.Namespace):
    """(the body's numbers, the fitted body or None): from --images when given (the body
    from photos), else the typed measurements (fitted later)."""
    if not getattr(args, "images", None):
        return _measurements(args), None
    from tryon.body.fit import TAPE_RANGE_CM
    from tryon.learn.body_from_photos import body_from_image_files

    typed = [f"--{k.replace('_', '-')}-cm" for k in ("chest", "waist", "hip", *TAPE_RANGE_CM)
             if getattr(args, f"{k}_cm", None) is not None]
    if typed or args.bmi is not None:
        raise TryonError(f"--images reads the body off the photos; leave out {', '.join(typed or ['--bmi'])} "
                         f"(give --height-cm, --gender and optionally --weight-kg)")
    pb = body_from_image_files(args.images, args.height_cm, args.gender, args.weight_kg, args.age)
    for note in pb.notes:
        print(f"note: {note}")
    m = pb.measurements()
    print(f"body from {len(args.images)} photo(s): {m['weight_kg']:.1f} kg, chest {m['chest_cm']:.1f}, waist "
          f"{m['waist_cm']:.1f}, hip {m['hip_cm']:.1f} cm ({pb.timings['total_s']:.1f} s)")
    return pb.request(), pb.fit


def _cmd_drape(args: argparse.Namespace) -> int:
    from tryon.drape import DrapeRequest, drape
    from tryon.drape.outputs import write_outputs

    size = None if args.size.lower() in ("mtm", "made-to-measure") else args.size
    out = check_output_dir(args.out, force=args.force)
    body, person = _person(args)
    req = DrapeRequest(body, garment=args.garment, size=size, fabric=args.fabric,
                       edge_length=args.edge_length, dt=args.dt, max_settle_time=args.settle_time,
                       print_image=args.print_image, print_width_cm=args.print_width_cm, allow_tight=args.allow_tight,
                       time_limit_s=args.time_limit)
    req.validate()
    if req.garment_obj is not None:  # a malformed garment is reported before the body is fitted
        from tryon.drape.obj_garment import garment_from_obj

        garment_from_obj(req.garment_obj)
    if args.method == "learned":
        from tryon.learn.drape import learned_drape

        result = learned_drape(req, args.model, refine=args.refine, person=person)
    elif args.model or args.refine:
        raise TryonError("--model and --refine belong to --method learned")
    else:
        result = drape(req, progress=not args.quiet, person=person)
    verdict = _fit_verdict(result, predicted=args.method == "learned" and not args.refine)
    if verdict:
        result.metrics["fit"] = verdict
    rep = write_outputs(result, out, force=args.force)
    a, b = rep["body"]["achieved"], rep["body"]["asked"]
    print(f"body: asked {b.get('height_cm'):.0f} cm / BMI {b.get('bmi', float('nan')):.1f}, achieved {a['height_cm']:.1f} cm / "
          f"{a['weight_kg']:.1f} kg / BMI {a['bmi']:.1f} (chest {a['chest_cm']:.0f}, waist {a['waist_cm']:.0f}, hip {a['hip_cm']:.0f} cm)")
    print(f"{req.garment} {rep['size'] or ''} in {req.fabric}: max strain {rep['max_strain'] * 100:.1f} %, mean {rep['mean_strain'] * 100:.1f} %, "
          f"penetration {rep['penetration_pct']:.2f} % of vertices, " + _how(rep) + f"; {rep['wall_s']:.1f} s -> {out}")
    if verdict:
        ease = (f"{verdict['decided_by']} ease {verdict['ease_cm']:.1f} cm, a regular fit "
                f"{verdict['target_ease_cm']:.1f} cm")
        print(f"fit: {'fits' if verdict['fits'] else 'does not fit'} ({'; '.join([ease, *verdict['why_not']])}; judged on "
              f"the {verdict['judged_on']}, as tryon size judges every size)")
    for note in rep.get("notes", []):
        print(f"note: {note}")
    return 0


def _fit_verdict(result, predicted: bool) -> dict | None:
    """Whether the draped size fits, judged as `tryon size` and the service judge it (a
    garment without pattern panels, from an OBJ, is not judged)."""
    from tryon.sizing.judge import judge_size

    if result.garment.pattern is None:
        return None
    j = judge_size(result.request.size or "made to measure", result, strain_reliable=not predicted)
    return {"fits": j["fits"], "why_not": j["why_not"], "torso_ease_cm": j["torso_ease_cm"], "decided_by": j["decided_by"],
            "ease_cm": j["ease_cm"], "target_ease_cm": j["target_ease_cm"],
            **{k: j[k] for k in ("waist_ease_cm", "inseam_excess_cm") if k in j},
            "judged_on": "prediction" if predicted else "refined drape" if result.metrics.get("method", "").startswith(
                "learned") else "simulated drape"}


def _how(rep: dict) -> str:
    """How the drape was made, for the one-line summary."""
    method = rep.get("method", "simulate")
    if method.startswith("learned"):
        how = f"predicted in {rep['timings']['inference_ms']:.0f} ms"
        if "refine_s" in rep["timings"]:
            how += f", refined in {rep['timings']['refine_s']:.1f} s ({rep['refine_steps']} steps, " \
                   f"{'at rest' if rep['settled'] else 'still moving'})"
        return how
    return f"{rep['steps']} steps, {'at rest' if rep['settled'] else 'still moving'}"


def _cmd_size(args: argparse.Namespace) -> int:
    from tryon.sizing.outputs import write_size_outputs
    from tryon.sizing.recommend import size_recommendation

    if args.workers < 1:
        raise TryonError(f"--workers must be at least 1, got {args.workers}")
    if (args.workers > 1 or args.ray_address) and args.method != "simulate":
        raise TryonError("--workers and --ray-address drape the sizes in parallel with --method simulate; a learned "
                         "drape takes seconds")
    out = check_output_dir(args.out, force=args.force)
    body, person = _person(args)
    rec, results = size_recommendation(body, garment=args.garment, fabric=args.fabric, method=args.method,
                                       refine=not args.no_refine, model_path=args.model, sizes=args.sizes,
                                       workers=args.workers, ray_address=args.ray_address, person=person)
    write_size_outputs(rec, results, out, force=args.force)
    print(f"recommended size: {rec['recommended']} ({rec['method']}, {rec['wall_s']:.1f} s)")
    for line in rec["reasons"]:
        print(f"  {line}")
    for note in rec["notes"]:
        print(f"note: {note}")
    print(f"-> {out}/size.json, {out}/sizes.png")
    return 0


def _cmd_animate(args: argparse.Namespace) -> int:
    from tryon.drape.animate import animate

    _check_positive(args, "dt", "duration")
    if args.method == "kdsm":
        from tryon.kdsm.animate import kdsm_animate

        from tryon.kdsm.model import shipped_model_path

        args.model = args.model or shipped_model_path("kdsm-hybrid")
        if args.resume or args.parallel == "time" or args.repeat != 1:
            raise TryonError("--resume, --parallel and --repeat belong to the simulated animation; a KDSM animation "
                             "takes seconds")
        rep = kdsm_animate(args.drape_dir, args.model, args.motion, out=args.out, duration=args.duration,
                           progress=not args.quiet, force=args.force, push_out=not args.no_push_out)
        print(f"{rep['motion']}: {rep['frames']} frames by {rep['method']} at {rep['ms_per_frame']:.1f} ms per frame "
              f"({rep['frames_per_second']:.0f} per second); penetration up to {rep['max_penetration_pct']:.2f} % of "
              f"vertices; {rep['wall_s']:.1f} s")
        return 0
    if args.model or args.no_push_out:
        raise TryonError("--model and --no-push-out belong to --method kdsm")
    rep = animate(args.drape_dir, args.motion, out=args.out, dt=args.dt, progress=not args.quiet, resume=args.resume,
                  run=_time_parallel_runner(args), duration=args.duration, force=args.force, repeat=args.repeat)
    print(f"{rep['motion']}: {rep['frames']} frames, {rep['steps']} steps in {rep['wall_s']:.1f} s; max strain "
          f"{rep['max_strain'] * 100:.1f} %, penetration up to {rep['max_penetration_pct']:.2f} % of vertices, "
          f"intersections {rep['intersections']}")
    return 0


def _time_parallel_runner(args: argparse.Namespace):
    """`run(scene, work_dir, progress, resume)` for `animate` under --parallel time, or None (serial)."""
    if args.parallel != "time":
        return None
    from tryon.parallel import run_scene_time_parallel

    def run(scene, work_dir, progress, resume):
        return run_scene_time_parallel(scene, work_dir, progress=progress, resume=resume, write_objs=False,
                                       options=_parallel_options(args), force=args.force)

    return run


def _pose_angles(items: list[str] | None) -> dict[str, float]:
    """`--pose NAME=DEG ...` as a dict (the names and ranges are checked by the live poser)."""
    angles = {}
    for item in items or []:
        name, sep, value = item.partition("=")
        try:
            angles[name] = float(value) if sep else float("nan")
        except ValueError:
            angles[name] = float("nan")
        if not math.isfinite(angles[name]):
            raise TryonError(f"--pose {item!r}: give NAME=DEGREES, e.g. arm_elevation.L=120")
    return angles


def _cmd_view(args: argparse.Namespace) -> int:
    import time

    from tryon.viewer import screenshot_viewer, start_server, write_viewer

    pose = _pose_angles(args.pose)
    live = None
    if args.live:
        from tryon.io.atomic import check_output_dir
        from tryon.kdsm.live import LivePoser, live_angles
        from tryon.kdsm.model import shipped_model_path
        from tryon.viewer.screenshot import find_browser

        if args.animation or args.no_serve:
            raise TryonError("--live poses the drape itself on a served page; leave out --animation and --no-serve")
        live_angles(pose)   # everything that can be refused is, before the model is set on the drape
        check_output_dir(Path(args.drape_dir) / "viewer", force=args.force)
        if args.screenshot:
            find_browser()
        live = LivePoser(args.drape_dir, args.model or shipped_model_path(from_rest=True))
    elif args.model or pose:
        raise TryonError("--model and --pose are for --live")
    out = write_viewer(args.drape_dir, animation=args.animation, force=args.force)
    print(f"viewer written to {out}")
    if args.screenshot:
        status = screenshot_viewer(out, args.screenshot, mode=args.mode, live=live, pose=pose)
        print(f"screenshot ({args.mode or 'default colouring'}) -> {args.screenshot}: {status}")
    if args.no_serve or args.screenshot:
        return 0
    server = start_server(out, args.port, live=live)
    url = f"http://127.0.0.1:{server.server_address[1]}/index.html"
    if pose:
        from urllib.parse import urlencode

        url += "?" + urlencode(pose)
    print(f"serving {url} (Ctrl-C to stop)")
    if args.open:
        import webbrowser

        webbrowser.open(url)
    try:
        while True:
            time.sleep(3600)
    except KeyboardInterrupt:
        server.shutdown()
    return 0


def _cmd_body_range(args: argparse.Namespace) -> int:
    from tryon.body.range import bmi_range_table

    rows = bmi_range_table(height_cm=args.height_cm)
    if args.json:
        from tryon.io.atomic import atomic_write

        with atomic_write(args.json) as fh:
            fh.write(dumps_json(rows, indent=2))
    for r in rows:
        print(f"{r['gender']:7s} {r['body']:12s} BMI asked {r['bmi_asked']:5.1f} achieved {r['bmi_achieved']:5.1f}  distortion {r['mesh_distortion']:.2f}  "
              f"largest local change {r['largest_local_change']:.2f}  {'ok' if r['supported'] else 'outside the supported range'}")
    if args.render:
        from tryon.body.range import render_range_sheet

        print(f"bodies -> {render_range_sheet(args.render, height_cm=args.height_cm)}")
    return 0


def _cmd_body_tapes(args: argparse.Namespace) -> int:
    from tryon.body.fit import fit_body
    from tryon.body.tape import TAPES, tape_measurements

    m = _measurements(args)
    if args.anny_average:
        extra = sorted(k for k in m.tapes() if k not in ("chest", "waist", "hip"))
        if extra:
            raise TryonError("--anny-average fits stature, weight and chest / waist / hip only; drop "
                             + ", ".join(f"--{k.replace('_', '-')}-cm" for k in extra))
    fit = fit_body(m, prior=not args.anny_average)
    tapes = tape_measurements(fit.shape)
    print(f"{'measurement':16s} {'body cm':>8s} {'asked':>7s} {'prior':>7s} {'prior sd':>8s}")
    for name in TAPES:
        key = f"{name}_cm"
        asked = f"{fit.asked[key]:.1f}" if key in fit.asked else ""
        prior = f"{fit.prior[key]:.1f}" if key in fit.prior else ""
        sd = f"{fit.prior_sd[key]:.1f}" if key in fit.prior_sd else ""
        print(f"{name:16s} {tapes[key]:8.1f} {asked:>7s} {prior:>7s} {sd:>8s}")
    print(f"weight {fit.achieved['weight_kg']:.1f} kg, BMI {fit.achieved['bmi']:.1f}; fitted in {fit.wall_s:.1f} s")
    for note in fit.notes:
        print(f"note: {note}")
    if args.json:
        from tryon.io.atomic import atomic_write

        with atomic_write(args.json) as fh:
            fh.write(dumps_json({"tapes_cm": tapes, **fit.report()}, indent=2))
    if args.render:
        from tryon.body.tape_picture import render_tapes

        print(f"tapes -> {render_tapes(args.render, fit.shape)}")
    return 0


def _cmd_body_prior(args: argparse.Namespace) -> int:
    from tryon.body.prior import PRIOR_JSON, default_prior, held_out, load_ansur, rebuild, regression_errors

    if args.rebuild:
        doc = rebuild()
        print(f"prior -> {PRIOR_JSON} (train {doc['split']['train']}, held out {doc['split']['test']} people)")
    _, test = held_out(load_ansur())
    errors = regression_errors(default_prior(), test)
    print("held-out ANSUR II people, each measurement from stature, weight, sex and age (mean relative error):")
    for name, pct in errors.items():
        print(f"  {name:20s} {pct:5.2f} %")
    return 0


def _cmd_body_warmstart(args: argparse.Namespace) -> int:
    from tryon.body.warmstart import WARMSTART_JSON
    from tryon.body.warmstart_build import build

    if not args.rebuild:
        raise TryonError("tryon body-warmstart only rebuilds (--rebuild): the warm start ships with tryon")
    doc = build(n=args.people, seed=args.seed)
    rms = ", ".join(f"{g} {d['train_rms']:.3f}" for g, d in doc["genders"].items())
    print(f"warm start -> {WARMSTART_JSON} ({args.people} fits per gender in {doc['build_s']:.0f} s; rms {rms})")
    return 0


def _cmd_fabric_classes(args: argparse.Namespace) -> int:
    from tryon.fabric import load_fabric
    from tryon.perceive.fabric_classes import build_classes, default_classes, save_classes

    if args.rebuild:
        print(f"fabric classes rewritten: {save_classes(build_classes(progress=True))}")
    classes = default_classes()
    presets = classes.preset_classes()
    if args.json:
        print(dumps_json({**classes.to_dict(), "presets": {n: classes.name(c) for n, c in presets.items()}}, indent=2))
        return 0
    print(f"{classes.count} classes: {classes.stretch_bins} stretching x {classes.bend_bins} bending bins "
          "(log10 stiffness, softest first; edges at equal steps of deformation)")
    print("stretching N/m: " + " | ".join(f"{10 ** a:.0f}-{10 ** b:.0f}" for a, b in zip(classes.stretch_edges,
                                                                                        classes.stretch_edges[1:])))
    print("bending uN.m:   " + " | ".join(f"{1e6 * 10 ** a:.1f}-{1e6 * 10 ** b:.1f}" for a, b in zip(classes.bend_edges,
                                                                                                   classes.bend_edges[1:])))
    for name, c in presets.items():
        s, b = classes.position(load_fabric(name))
        print(f"{name:20s} {classes.name(c):6s} stretch {10 ** s:6.0f} N/m, bending {1e6 * 10 ** b:5.1f} uN.m")
    return 0


def _cmd_fabrics(args: argparse.Namespace) -> int:
    from tryon.fabric import preset_summaries

    if args.classes or args.rebuild:
        return _cmd_fabric_classes(args)

    rows = preset_summaries()
    if args.json:
        print(dumps_json(rows, indent=2))
        return 0
    print(f"{'name':20s} {'g/m2':>6s} {'stretch u/v/shear N/m':>22s} {'at 16% strain':>16s} {'bend u/v uN.m':>14s}  composition")
    for r in rows:
        st, st16, bend = r["stretch_N_m"], r.get("stretch_N_m_at_16pct") or r["stretch_N_m"], r["bending_N_m"]
        small = f"{st['warp_u']:.0f}/{st['weft_v']:.0f}/{st['shear']:.0f}"
        large = f"{st16['warp_u']:.0f}/{st16['weft_v']:.0f}/{st16['shear']:.0f}"
        if isinstance(bend, dict):
            bend_txt = f"{bend['edge_along_u'] * 1e6:.1f}/{bend['edge_along_v'] * 1e6:.1f}"
        else:
            bend_txt = f"{bend * 1e6:.1f}"
        print(f"{r['name']:20s} {r['density_kg_m2'] * 1000:6.0f} {small:>22s} {large:>16s} {bend_txt:>14s}  {r['composition']}")
    return 0


BENCHES = ["sim", "robustness", "drape", "grad", "parallel", "learned", "ablations", "fidelity", "fit-fabric", "print", "kdsm",
           "size", "anthropometry", "body", "serve", "perceive"]


def _cmd_bench(args: argparse.Namespace) -> int:
    if args.what == "serve":
        from tryon.bench.serve import run_serve_bench

        if args.shoppers < 1 or args.duration <= 0 or args.fault_duration <= 0:
            raise TryonError("give at least 1 --shoppers and positive --duration and --fault-duration (seconds)")
        quick = args.quick
        run_serve_bench(args.json, shoppers=2 if quick else args.shoppers, duration_s=30 if quick else args.duration,
                        fault_duration_s=30 if quick else args.fault_duration, workers=max(args.workers),
                        faults=tuple(args.faults))
        return 0
    if args.what == "body":
        from tryon.bench.body import run_body_bench

        for name in ("people", "drapes"):
            if getattr(args, name) is not None and getattr(args, name) < (0 if name == "drapes" else 1):
                raise TryonError(f"--{name} {getattr(args, name)}: give a count of at least {0 if name == 'drapes' else 1}")
        run_body_bench(args.json, data=args.data, model=args.model, people=args.people or (4 if args.quick else 60),
                       drapes=args.drapes)
        return 0
    if args.what == "anthropometry":
        from tryon.bench.anthropometry import run_anthropometry_bench

        run_anthropometry_bench(args.json, per_sex=args.people or (3 if args.quick else 30))
        return 0
    if args.what == "sim":
        from tryon.bench.sim import run_sim_bench

        run_sim_bench(args.json, quick=args.quick, threads=args.threads, grids=args.grids)
        return 0
    if args.what == "robustness":
        from tryon.bench.robustness import run_robustness_bench

        grid = args.grids[0] if args.grids != DEFAULT_GRIDS else 16
        run_robustness_bench(args.json, resolution=grid, duration=0.2 if args.quick else 0.5)
        return 0
    if args.what == "grad":
        from tryon.bench.grad import run_grad_bench

        run_grad_bench(args.json, quick=args.quick)
        return 0
    if args.what == "parallel":
        from tryon.bench.parallel import run_parallel_bench

        run_parallel_bench(args.json, quick=args.quick, workers=args.workers, only=args.only)
        return 0
    if args.what == "learned":
        from tryon.bench.learned import run_learned_bench

        if args.per_split is not None and args.per_split < 1:
            raise TryonError(f"--per-split must be at least 1, got {args.per_split}")
        data = args.data
        if not data:
            if args.model:
                raise TryonError("tryon bench learned --model needs --data DATASET (the held-out drapes that ship "
                                 "belong to the shipped model)")
            from tryon.learn.model import shipped_eval_data_path

            data = str(shipped_eval_data_path("tshirt"))
        run_learned_bench(args.json, data, model_path=args.model, quick=args.quick, per_split=args.per_split)
        return 0
    if args.what == "size":
        from tryon.bench.size import run_size_bench

        run_size_bench(args.json, model_path=args.model, quick=args.quick)
        return 0
    if args.what == "kdsm":
        from tryon.bench.kdsm import run_kdsm_bench

        if not args.data:
            raise TryonError("tryon bench kdsm needs --data POSES (a pose dataset from tryon dataset poses) and "
                             "--models MODEL.npz ... (tryon train kdsm)")
        run_kdsm_bench(args.json, args.data, args.models or [], stride=4 if args.quick else 1, drape=args.drape,
                       motion=args.motion)
        return 0
    if args.what == "print":
        from tryon.bench.prints import run_print_bench

        if not args.data:
            raise TryonError("tryon bench print needs --data DATASET (a drape dataset the model was trained on)")
        run_print_bench(args.json, args.data, model_path=args.model, count=2 if args.quick else 6)
        return 0
    if args.what == "ablations":
        from tryon.bench.ablations import run_ablations

        if not args.data:
            raise TryonError("tryon bench ablations needs --data DATASET (a drape dataset from tryon dataset drape)")
        run_ablations(args.json, args.data, names=args.only, epochs=args.epochs or (4 if args.quick else 40))
        return 0
    if args.what == "fidelity":
        from tryon.bench.fidelity import run_fidelity_bench

        run_fidelity_bench(args.json, reference=args.reference)
        return 0
    if args.what == "perceive":
        from tryon.bench.perceive import CHAPTER_FABRICS, run_perceive_bench

        quick = args.quick
        run_perceive_bench(args.json, clips=args.data, model_path=args.model,
                           presets=CHAPTER_FABRICS[:1] if quick else CHAPTER_FABRICS, per_fabric=1 if quick else 2,
                           limit=1 if quick else None)
        return 0
    if args.what == "fit-fabric":
        from tryon.bench.fit_fabric import HELD_OUT, run_fit_fabric_bench

        run_fit_fabric_bench(args.json, reference=args.reference, held_out=() if args.quick else HELD_OUT,
                             all_steps=not args.quick)
        return 0
    if args.what == "drape" and args.matrix:
        from tryon.bench.drape_matrix import run_drape_matrix

        run_drape_matrix(args.json, quick=args.quick, bodies=args.bodies)
        return 0
    if args.what == "drape":
        from tryon.bench.drape import run_drape_bench

        run_drape_bench(args.json, quick=args.quick)
        return 0
    raise TryonError(f"unknown benchmark {args.what!r}; available: {', '.join(BENCHES)}")


def _parallel_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--parallel", choices=["time"], help="time-domain parallel simulation (coarse-to-fine segments on Ray)")
    p.add_argument("--workers", type=int, default=2, help="parallel workers (segments run at once)")
    p.add_argument("--partition", choices=["uniform", "balanced", "adaptive"], default="adaptive",
                   help="where segments start (see docs/PARALLEL.md)")
    p.add_argument("--ray-address", help="join this Ray cluster instead of starting a local one")
    p.add_argument("--coarse-dt-ratio", type=int, metavar="R",
                   help="the coarse run takes time steps R times the fine one (cheaper coarse run, larger K; "
                        "default 4 for garment animations, 1 otherwise)")
    p.add_argument("--crossfade", type=float, default=0.2, metavar="SECONDS",
                   help="each segment runs this long past its end and the join cross-fades it into the next "
                        "segment's start, so boundaries do not pop (0: segments meet in one frame)")


def _parallel_options(args: argparse.Namespace):
    from tryon.parallel import ParallelOptions

    return ParallelOptions(workers=args.workers, partition=args.partition, ray_address=args.ray_address,
                           dt_ratio=args.coarse_dt_ratio, crossfade=args.crossfade)


def _body_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--height-cm", type=float, required=True, help="stature in cm")
    p.add_argument("--weight-kg", type=float, help="body mass in kg (or give --bmi)")
    p.add_argument("--bmi", type=float, help="body mass index (instead of --weight-kg)")
    p.add_argument("--gender", choices=["male", "female"], required=True)
    p.add_argument("--age", type=float, default=30.0, help="years")
    p.add_argument("--chest-cm", type=float, help="chest / bust girth at the bust point (optional)")
    p.add_argument("--waist-cm", type=float, help="natural waist girth, the narrowest (optional)")
    p.add_argument("--hip-cm", type=float, help="hip girth at the fullest part of the buttocks (optional)")
    p.add_argument("--waist-navel-cm", type=float, help="waist girth at the navel (optional)")
    p.add_argument("--neck-cm", type=float, help="neck girth at its base (optional)")
    p.add_argument("--thigh-cm", type=float, help="thigh girth at the top of the thigh (optional)")
    p.add_argument("--crotch-height-cm", "--inseam-cm", dest="crotch_height_cm", type=float,
                   help="crotch height above the floor, the inseam (optional)")
    p.add_argument("--shoulder-width-cm", type=float, help="distance between the shoulder points (acromia) (optional)")
    p.add_argument("--arm-length-cm", type=float, help="shoulder point over the elbow to the wrist (optional)")
    p.add_argument("--waist-height-cm", type=float, help="navel above the floor (optional)")
    p.add_argument("--wrist-cm", type=float, help="wrist girth (optional)")


def _images_arg(p: argparse.ArgumentParser) -> None:
    p.add_argument("--images", nargs="+", metavar="IMG",
                   help="1-4 photos of the person, head to feet (the body from photos: give --height-cm, --gender "
                        "and optionally --weight-kg; see tryon body from-images)")


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="tryon", description="Simulation-based virtual try-on.")
    sub = p.add_subparsers(dest="command", required=True)

    s = sub.add_parser("simulate", help="run a cloth scene (YAML or a built-in example)")
    s.add_argument("scene", nargs="?", help="scene YAML file")
    s.add_argument("--example", help="built-in scene: hanging, sphere-drop, table, pyramid")
    s.add_argument("--out", help="output directory (default out/<scene>)")
    s.add_argument("--resolution", type=int, help="grid vertices per side for --example")
    s.add_argument("--dt", type=float, help="time step in seconds (overrides the scene)")
    s.add_argument("--duration", type=float, help="simulated seconds (overrides the scene)")
    s.add_argument("--fabric", help="fabric preset or .json (overrides the scene)")
    s.add_argument("--linear-solver", choices=["auto", "pcg-two-level", "pcg", "cholmod", "splu"])
    s.add_argument("--resume", action="store_true", help="continue an interrupted run from its checkpoint")
    s.add_argument("--no-obj", action="store_true", help="skip the OBJ sequence")
    s.add_argument("--dump", action="store_true", help="print the example's YAML and exit")
    s.add_argument("--quiet", action="store_true")
    _parallel_args(s)
    _force_arg(s)
    s.set_defaults(func=_cmd_simulate)

    d = sub.add_parser("drape", help="a garment of a size and fabric on a body from measurements")
    _body_args(d)
    _images_arg(d)
    d.add_argument("--garment", default="tshirt",
                   help="tshirt, longsleeve, skirt, trousers, dress, or a garment .obj around the body (vt: material coords in m)")
    d.add_argument("--size", default="M", help="XS, S, M, L, XL, XXL or made-to-measure")
    d.add_argument("--fabric", default="gray-interlock", help="fabric preset or .json")
    d.add_argument("--edge-length", type=float, default=0.012, help="garment triangle edge length in metres")
    d.add_argument("--dt", type=float, default=0.01, help="time step in seconds")
    d.add_argument("--allow-tight", action="store_true",
                   help="drape a size far too small for the body (refused by default) to see how it strains")
    d.add_argument("--settle-time", type=float, default=3.0, help="longest simulated settling time after the morph (s)")
    d.add_argument("--time-limit", type=float, default=600.0,
                   help="wall-clock seconds the simulated drape may take; past them it stops after the step in progress and says where it is stuck")
    d.add_argument("--method", choices=["simulate", "learned"], default="simulate",
                   help="simulate the drape, or predict it with the trained network (milliseconds; standard sizes it knows)")
    d.add_argument("--model", help="a draping model file (tryon train drape) instead of the one shipped for the garment")
    d.add_argument("--refine", action="store_true",
                   help="learned: relax the prediction with the simulator (no vertex inside the body; seconds)")
    d.add_argument("--print", dest="print_image", metavar="PNG",
                   help="an image printed on the front panel: drawn on the draped garment, and heavier and stiffer "
                        "than the fabric where its alpha covers (tshirt, longsleeve, dress)")
    d.add_argument("--print-width-cm", type=float, default=24.0, help="the print's width on the panel (cm)")
    d.add_argument("--out", default="out/drape", help="output directory")
    d.add_argument("--quiet", action="store_true")
    _force_arg(d)
    d.set_defaults(func=_cmd_drape)

    z = sub.add_parser("size", help="recommend a size: drape every size, score ease, strain and pressure per region")
    _body_args(z)
    _images_arg(z)
    z.add_argument("--garment", default="tshirt", help="a garment with a learned model (tshirt)")
    z.add_argument("--fabric", default="gray-interlock", help="fabric preset or .json")
    z.add_argument("--sizes", nargs="+", help="sizes to compare (default: every size the model knows)")
    z.add_argument("--method", choices=["learned", "simulate"], default="learned",
                   help="predict each size's drape (refined by the simulator), or simulate it (minutes)")
    z.add_argument("--no-refine", action="store_true", help="learned: skip the simulator's refinement")
    z.add_argument("--model", help="a draping model file instead of the shipped one")
    z.add_argument("--workers", type=int, default=1,
                   help="simulate: drape this many sizes at once as Ray tasks (a local Ray; one CPU each)")
    z.add_argument("--ray-address", help="simulate: drape the sizes on this Ray cluster")
    z.add_argument("--out", default="out/size", help="output directory (size.json, sizes.png)")
    z.add_argument("--quiet", action="store_true")
    z.add_argument("--force", action="store_true", help="use an existing --out folder tryon did not write")
    z.set_defaults(func=_cmd_size)

    a = sub.add_parser("animate", help="the garment of a drape following a body motion")
    a.add_argument("drape_dir", help="output directory of `tryon drape`")
    a.add_argument("--motion", default="walk", help="walk, arm-raise, turn, or a motion .npz / .bvh file")
    a.add_argument("--out", help="output directory (default DRAPE_DIR/animation-MOTION)")
    a.add_argument("--dt", type=float, default=0.01, help="time step in seconds")
    a.add_argument("--duration", type=float, help="simulated seconds (default: the whole motion)")
    a.add_argument("--repeat", type=int, default=1, help="play a cyclic motion (walk) this many times in a row")
    a.add_argument("--resume", action="store_true", help="continue an interrupted animation from its checkpoint")
    a.add_argument("--method", choices=["simulate", "kdsm"], default="simulate",
                   help="simulate the garment, or predict it pose by pose with a trained KDSM model (--model)")
    a.add_argument("--model", help="kdsm: a model file from tryon train kdsm (default: the shipped hybrid, T-shirt M)")
    a.add_argument("--no-push-out", action="store_true",
                   help="kdsm: keep the network's cloth where it puts it, even inside the body (default: moved out)")
    a.add_argument("--quiet", action="store_true")
    _parallel_args(a)
    _force_arg(a)
    a.set_defaults(func=_cmd_animate)

    v = sub.add_parser("view", help="a local web page (three.js) of a drape or animation")
    v.add_argument("drape_dir", help="output directory of `tryon drape`")
    v.add_argument("--animation", help="show DRAPE_DIR/animation-NAME (from `tryon animate`) instead of the drape")
    v.add_argument("--port", type=int, default=8765, help="local port (0: any free port)")
    v.add_argument("--open", action="store_true", help="open the page in the default browser")
    v.add_argument("--no-serve", action="store_true", help="only write DRAPE_DIR/viewer")
    v.add_argument("--screenshot", help="save a picture of the page (headless Chromium) to this PNG instead of serving")
    v.add_argument("--mode", choices=["strain", "pressure", "plain"],
                   help="colouring for --screenshot (default: strain; the fabric for --live or a network's animation)")
    v.add_argument("--force", action="store_true", help="replace DRAPE_DIR/viewer even if tryon did not write it")
    v.add_argument("--live", action="store_true",
                   help="pose sliders: the garment in each pose predicted by a KDSM model as the sliders move")
    v.add_argument("--model", help="--live: the KDSM model (default: the shipped hybrid trained on poses from rest, T-shirt M)")
    v.add_argument("--pose", nargs="+", metavar="NAME=DEG",
                   help="--live: where sliders start, e.g. arm_elevation.L=120 elbow_flexion.R=60")
    v.set_defaults(func=_cmd_view)

    r = sub.add_parser("body-range", help="the BMI range the Anny body reaches without distortion")
    r.add_argument("--height-cm", type=float, default=172.0)
    r.add_argument("--json", help="also write the table as JSON")
    r.add_argument("--render", help="also render the bodies (front views, BMI 14-48) into this PNG")
    r.set_defaults(func=_cmd_body_range)

    t = sub.add_parser("body-tapes", help="fit a body and report every tape measurement (ISO 8559-1 / ANSUR II "
                       "landmarks), with the ANSUR II prior's value for each")
    _body_args(t)
    t.add_argument("--anny-average", action="store_true",
                   help="Anny's average shape of the stature and weight instead of the ANSUR II prior's")
    t.add_argument("--json", help="also write the tapes and the fit report as JSON")
    t.add_argument("--render", help="also draw the tapes on the body (front and side) into this PNG")
    t.set_defaults(func=_cmd_body_tapes)

    q = sub.add_parser("body-prior", help="the ANSUR II prior's errors on held-out people (--rebuild: fit it again)")
    q.add_argument("--rebuild", action="store_true", help="fit the prior on the training split and write it")
    q.set_defaults(func=_cmd_body_prior)

    w = sub.add_parser("body-warmstart", help="rebuild the body fit's warm start (cold fits of people across the range)")
    w.add_argument("--rebuild", action="store_true", help="fit the people and write the warm start")
    w.add_argument("--people", type=int, default=160, help="people per gender (default 160)")
    w.add_argument("--seed", type=int, default=0)
    w.set_defaults(func=_cmd_body_warmstart)

    f = sub.add_parser("fabrics", help="list fabric presets (--classes: the 54 fabric classes of fabric from video)")
    f.add_argument("--json", action="store_true")
    f.add_argument("--classes", action="store_true",
                   help="the fabric classes: bin edges, and the class of every measured fabric")
    f.add_argument("--rebuild", action="store_true",
                   help="with --classes: measure the sensitivity tests again and rewrite the shipped bin edges")
    f.set_defaults(func=_cmd_fabrics)

    b = sub.add_parser("bench", help="measure speed (JSON out, ratios against references)")
    b.add_argument("what", choices=BENCHES)
    b.add_argument("--json", default="bench.json", help="output JSON path")
    b.add_argument("--quick", action="store_true", help="fewer steps (smoke run)")
    b.add_argument("--threads", type=int, nargs="+", default=[1, 2])
    b.add_argument("--grids", type=int, nargs="+", default=DEFAULT_GRIDS,
                   help="grid sizes (sim); the first one is the grid of the robustness runs (default 16)")
    b.add_argument("--workers", type=int, nargs="+", default=[1, 2],
                   help="worker counts (parallel); serve: refinement workers (the largest given)")
    b.add_argument("--shoppers", type=int, default=8, help="serve: concurrent shoppers")
    b.add_argument("--duration", type=float, default=300.0, help="serve: seconds of load without a fault")
    b.add_argument("--faults", nargs="*", default=["worker_killed", "server_restarted"],
                   choices=["worker_killed", "server_restarted"], help="serve: the faults run after the plain load (none: give none)")
    b.add_argument("--fault-duration", type=float, default=90.0,
                   help="serve: seconds of load with a worker killed, then with the server restarted, halfway")
    b.add_argument("--data", help="learned, print: the drape dataset whose test splits are judged (learned: default "
                                  "the shipped model's held-out drapes); kdsm: the pose dataset; body: the photo "
                                  "dataset (default data/bodies-v1); perceive: held-out clips (default: clips of "
                                  "the chapter's five measured fabrics, made next to --json)")
    b.add_argument("--model", help="learned, size: a model file instead of the shipped one; perceive: an image-only "
                                   "fabric classifier (default: the true class, what a right classifier gives)")
    b.add_argument("--per-split", type=int, metavar="N",
                   help="learned: judge at most N drapes of each held-out split, evenly spread (refinement takes seconds each)")
    b.add_argument("--models", nargs="+", help="kdsm: trained models to judge (tryon train kdsm; models of one method "
                   "are told apart by their folder)")
    b.add_argument("--drape", help="kdsm: a drape of the models' garment to animate against the simulator (with the "
                   "dynamics gap: the simulator's own cloth from rest at 8 frames against its animation)")
    b.add_argument("--motion", help="kdsm: the held-out motion (.npz/.bvh; default: random key poses of an unused seed)")
    b.add_argument("--only", nargs="+", metavar="NAME",
                   help="ablations: these variants only; parallel: these scenes only (animate-walk, animate-arm-raise, "
                        "sphere-drop); default: all")
    b.add_argument("--epochs", type=int, help="ablations: epochs per variant (default 40; --quick 4)")
    b.add_argument("--reference", metavar="DIR",
                   help="fidelity, fit-fabric: a folder of ARCSim runs (*.npz, ground truth included; default: the copy "
                        "in the package)")
    b.add_argument("--people", type=int, metavar="N",
                   help="anthropometry: held-out ANSUR II people per sex, spread over the BMI range (default 30); "
                        "body: test people of the photo dataset (default 60)")
    b.add_argument("--drapes", type=int, default=0, metavar="N",
                   help="body: also drape a T-shirt M on N test people's bodies from four renders and on their true "
                        "bodies (a minute or two each; pictures next to --json)")
    b.add_argument("--matrix", action="store_true",
                   help="drape: every garment on twelve bodies in two fabrics (resumable; picture grid next to --json)")
    b.add_argument("--bodies", nargs="+", metavar="KEY",
                   help="drape --matrix: only these bodies' rows, by key (f175-bmi45, m200-bmi45, ...)")
    b.set_defaults(func=_cmd_bench)

    from tryon.cli.dataset import add_commands as add_dataset_commands
    from tryon.cli.inverse import add_commands as add_inverse_commands
    from tryon.cli.learned import add_commands as add_learned_commands
    from tryon.cli.perceive import add_commands as add_perceive_commands
    from tryon.cli.serve import add_commands as add_serve_commands

    add_inverse_commands(sub)
    add_perceive_commands(sub)
    add_dataset_commands(sub)
    add_learned_commands(sub)
    add_serve_commands(sub)
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if getattr(args, "allow_large", False):
        os.environ[ALLOW_LARGE_ENV] = "1"
    try:
        return int(args.func(args) or 0)
    except TryonError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
    except SystemError as exc:  # Ctrl-C inside a compiled kernel surfaces as SystemError
        if not _interrupted(exc):
            raise
        print("interrupted", file=sys.stderr)
        return 130


def _interrupted(exc: BaseException | None) -> bool:
    while exc is not None:
        if isinstance(exc, KeyboardInterrupt):
            return True
        exc = exc.__cause__ or exc.__context__
    return False


if __name__ == "__main__":
    sys.exit(main())
