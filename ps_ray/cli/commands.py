"""`ps-ray` command line. Bad input exits non-zero with one line naming the bad value."""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import json
import os
import sys
import time
from pathlib import Path

from ps_ray.cli.args import flag_of
from ps_ray.cli.listing import cmd_list
from ps_ray.cli.parsers import STAGE_FLAGS, build_parser
from ps_ray.cli.paths import output_file
from ps_ray.errors import UserError
from ps_ray.pipeline.stage import StageError, StageInterrupted, raise_on_errors
from ps_ray.specs import reset_seeds
from ps_ray.specs.names import parse_spec_text
from ps_ray.specs.train import TrainSpec
from ps_ray.store.layout import sweep_layout
from ps_ray.store.lock import folder_lock


def cmd_train(args: argparse.Namespace) -> int:
    fields = {f.name: getattr(args, f.name) for f in dataclasses.fields(TrainSpec)}
    from ps_ray.envs.robots import resolve_robot
    from ps_ray.envs.tasks import resolve_task

    for key, resolve in (("robot", resolve_robot), ("task", resolve_task)):
        try:  # each checked on its own, so its error names its own flag
            fields[key] = parse_spec_text(getattr(args, key))
            if args.env is None:  # a gymnasium env by id stands in for robot and task
                resolve(fields[key])
        except (UserError, ValueError, TypeError) as e:
            raise UserError(f"--{key}: {e}") from None
    try:
        spec = TrainSpec.from_mapping(fields)
    except UserError as e:  # name the flag the bad value came from
        named = flag_of(str(e), fields)
        raise UserError(f"--{named.replace('_', '-')}: {e}" if named else str(e)) from None
    run_dir = Path(args.run_dir or Path("runs") / spec.slug())
    from ps_ray.rllib.train import train  # torch and Ray: only once the flags are good

    train(spec, run_dir, progress=not args.quiet, compile=args.compile)
    return 0


def cmd_grid(args: argparse.Namespace) -> int:
    from ps_ray.rllib.grid_train import train_grid
    from ps_ray.specs.grid import GridSpec

    fields = {f.name: getattr(args, f.name) for f in dataclasses.fields(TrainSpec) if hasattr(args, f.name)}
    try:
        base = TrainSpec.from_mapping(fields)
    except UserError as e:  # name the flag the bad value came from
        named = flag_of(str(e), fields)
        raise UserError(f"--{named.replace('_', '-')}: {e}" if named else str(e)) from None
    parts = {}
    for flag in ("robots", "tasks"):
        try:
            parts[flag] = [parse_spec_text(text) for text in getattr(args, flag)]
        except UserError as e:
            raise UserError(f"--{flag}: {e}") from None
    try:
        grid = GridSpec.of(base, parts["robots"], parts["tasks"], args.held_out)
    except (ValueError, TypeError) as e:  # an unknown robot or task, named
        raise UserError(str(e)) from None
    train_grid(grid, Path(args.run_dir), progress=not args.quiet)
    return 0


def cmd_sweep(args: argparse.Namespace) -> int:
    from ps_ray.pipeline.sweep import check_inputs

    spec = _load(args)
    check_inputs(spec)  # the files it starts from, before any folder is made
    counts = f"{len(spec.trials())} training trials"
    if spec.population > 1:  # sources in fewer trials
        from ps_ray.plan.train import plan

        counts = f"{len(spec.trials())} sources in {len(plan(spec))} trials of up to {spec.population}"
    print(f"sweep {spec.name!r}: {counts}")
    if args.check:
        from ps_ray.cli.check import print_check

        return print_check(spec, args.cores)
    from ps_ray.pipeline.sweep import run_sweep

    if "train" not in spec.stages:  # it would train sources that none of its stages reads
        stages = ", ".join(spec.stages)
        raise UserError(f"sweep {spec.name!r} has no train stage (stages: {stages}); ps-ray run runs them")
    with _sweep_lock(spec):
        results = run_sweep(spec, resume=args.resume)
    errors = [r for r in results if r.error]
    print(
        f"sweep {spec.name!r}: {len(results) - len(errors)}/{len(results)} trials finished; "
        f"results in {sweep_layout(spec).root}"
    )
    raise_on_errors(results, "training trials")
    return 0


def _load(args: argparse.Namespace):
    """The sweep spec named on the command line, with --storage/--tracking-uri applied."""
    from ps_ray.specs.sweep import load_stored_sweep, load_sweep

    path = Path(args.sweep)
    sets = getattr(args, "set", None) or []
    if path.is_dir():  # a sweep folder: its resolved spec, stored where the folder is
        if sets:
            raise UserError(f"{path}: --set applies to a sweep file; a sweep folder keeps the spec it ran")
        from ps_ray.store.layout import SweepLayout

        spec_file = SweepLayout(path).spec_file
        if not spec_file.exists():
            raise UserError(f"{path}: not a sweep folder (no {spec_file.name})")
        spec = dataclasses.replace(load_stored_sweep(spec_file), storage=str(path.resolve().parent))
        if spec.name != path.resolve().name:
            raise UserError(
                f"{path}: holds sweep {spec.name!r}; a sweep folder must keep its "
                f"sweep's name (rename it back to {spec.name!r})"
            )
    else:
        spec = load_sweep(path, sets)
    overrides = {
        k: v
        for k, v in (("storage", args.storage), ("tracking_uri", getattr(args, "tracking_uri", None)))
        if v
    }
    spec = dataclasses.replace(spec, **overrides) if overrides else spec
    if spec.tracking_uri:  # a store MLflow cannot use is refused before any folder is made
        from ps_ray.store.tracking import check_tracking_uri

        check_tracking_uri(spec.tracking_uri)
    return spec


def _sweep_lock(spec):
    """Held for the whole command: a second driver on the same sweep is refused in one line."""

    return folder_lock(sweep_layout(spec).root, "sweep")


def _given(args: argparse.Namespace, *names: str) -> dict:
    out = {n: getattr(args, n) for n in names if getattr(args, n) is not None}
    if "methods" in out:
        out["methods"] = tuple(out["methods"])
    return out


@contextlib.contextmanager
def _trained_sweep(args: argparse.Namespace, stage: str):
    """The sweep spec with a stage's flags applied and checked (as if written in the YAML), held
    under the sweep's lock. An untrained sweep is refused in one line and no folder is made; a
    sweep another driver holds is refused as locked, even while its training is still starting."""

    spec = _load(args)
    settings = dataclasses.replace(getattr(spec, stage), **_given(args, *STAGE_FLAGS.get(stage, ())))
    spec = dataclasses.replace(spec, **{stage: settings})  # checked like the YAML's own settings
    untrained = UserError(
        f"{sweep_layout(spec).root}: no trained sweep there; train it first (ps-ray sweep {args.sweep})"
    )
    if not sweep_layout(spec).root.is_dir():
        raise untrained
    with _sweep_lock(spec):
        if not sweep_layout(spec).spec_file.exists():
            raise untrained
        yield spec


def cmd_zero_shot(args: argparse.Namespace) -> int:
    from ps_ray.pipeline.zero_shot import run_zero_shot
    from ps_ray.pipeline.zero_shot_table import summary

    with _trained_sweep(args, "zero_shot") as spec:
        table = run_zero_shot(spec, resume=args.resume)
    columns = ["method", "pairing", "seed", "label", "success_mean", "best_unstitched", "chance_success"]
    columns += ["task_blind_success", "wrong_target_mean", "oracle_success", "transfer_gain"]
    print(table[columns].to_string(index=False, float_format=lambda x: f"{x:.2f}"))
    print(summary(table).to_string(float_format=lambda x: f"{x:.2f}"))
    return 0


def cmd_few_shot(args: argparse.Namespace) -> int:
    from ps_ray.pipeline.few_shot import curves, run_few_shot

    with _trained_sweep(args, "few_shot") as spec:
        results = run_few_shot(spec, resume=args.resume)
    for key, points in sorted(curves(results).items()):
        print(key, " ".join(f"{steps}:{success:.2f}" for steps, success in points))
    raise_on_errors(results, "few-shot trials")
    return 0


def cmd_run(args: argparse.Namespace) -> int:
    from ps_ray.analysis.cost import budget_note, project
    from ps_ray.pipeline.run import run_pipeline
    from ps_ray.pipeline.sweep import check_inputs
    from ps_ray.store.tracking import default_tracking_uri, runs_page

    spec = _load(args)
    check_inputs(spec)  # the files it starts from, before any folder is made
    if args.check:
        from ps_ray.cli.check import print_check

        print(f"sweep {spec.name!r}: stages {', '.join(spec.stages)}")
        return print_check(spec, args.cores)
    started = time.time()
    print(f"sweep {spec.name!r}: stages {', '.join(spec.stages)}; results in {sweep_layout(spec).root}")
    projection = project(spec)
    print(
        f"sweep {spec.name!r}: projected {projection.core_s / 3600:.2f} core-hours, about "
        f"{projection.wall_s_here / 60:.0f} min on this machine; rates: {projection.rates.source}"
    )
    with _sweep_lock(spec):
        summaries = run_pipeline(spec)
    print(f"sweep {spec.name!r}: all stages done in {(time.time() - started) / 60:.1f} min")
    if "report" in summaries:
        print(f"report: {sweep_layout(spec).report / 'index.html'}")
    uri = spec.tracking_uri or default_tracking_uri(sweep_layout(spec).root)
    print(f"MLflow: mlflow ui --workers 1 --backend-store-uri {uri}")  # one reader (docs/cost.md)
    if (page := runs_page(uri, spec.name)) is not None:
        print(f"        then open {page}")
    if note := budget_note(spec):
        print(f"note: {note}")
    return 0


def cmd_report(args: argparse.Namespace) -> int:
    from ps_ray.analysis.report import build_report

    if args.screenshot:  # a place that cannot hold it is refused before the report is built
        output_file(args.screenshot)
    with _trained_sweep(args, "report") as spec:
        page = build_report(spec, log_to_mlflow=not args.no_mlflow)
    print(f"report: {page}")
    if args.screenshot:
        from ps_ray.analysis.browser import screenshot

        print(f"screenshot: {screenshot(page, args.screenshot)}")
    return 0


def cmd_render(args: argparse.Namespace) -> int:
    from ps_ray.envs.robots import resolve_robot
    from ps_ray.envs.tasks import resolve_task

    if args.png is None and args.gif is None:
        raise UserError("nothing to write: give --png and/or --gif")
    robot, task = parse_spec_text(args.robot), parse_spec_text(args.task)
    resolve_robot(robot), resolve_task(task)  # bad names fail before any folder is made
    policy = None
    if args.policy:
        from ps_ray.nets.policy import GreedyPolicy
        from ps_ray.stitching.rule import target_problems
        from ps_ray.store.signature import read_signature

        problems = target_problems(read_signature(args.policy)[0], (robot, task))
        if problems:  # a policy used on another env
            raise UserError(f"{args.policy}: cannot run here: " + "; ".join(problems))
        policy = GreedyPolicy.from_file(args.policy)
    for flag, path in (("png", args.png), ("gif", args.gif)):
        if path is not None and Path(path).suffix.lower() != f".{flag}":
            raise UserError(
                f"--{flag} {path}: the image is written as {flag}; valid file names end in .{flag}"
            )
    for path in (args.png, args.gif):
        if path:
            output_file(path)
    from ps_ray.envs.render import record  # torch: only once the flags are good

    record(robot, task, policy, seed=args.seed, png=args.png, gif=args.gif)
    print(f"wrote {' and '.join(p for p in (args.png, args.gif) if p)}")
    return 0


def cmd_stitch(args: argparse.Namespace) -> int:
    from ps_ray.nets.policy_file import save_policy
    from ps_ray.stitching.evaluate import evaluate, format_result
    from ps_ray.stitching.sources import resolve_source, resolve_target
    from ps_ray.stitching.stitch import stitch_metadata, stitch_policies, translation_ridge
    from ps_ray.stitching.zoo import ModuleZoo

    if args.episodes < 0:
        raise UserError(f"--episodes must be >= 0, got {args.episodes}")
    if args.episodes == 0 and not args.save:
        raise UserError("--episodes 0 without --save does nothing; give --save FILE or --episodes N > 0")
    zoo = ModuleZoo.from_sweep(*args.sweep) if args.sweep else None
    task_src, robot_src = resolve_source(args.task_from, zoo), resolve_source(args.robot_from, zoo)
    robot, task = resolve_target(
        task_src,
        robot_src,
        robot=args.robot and parse_spec_text(args.robot),
        task=args.task and parse_spec_text(args.task),
    )
    states = None
    if args.translate:
        from ps_ray.pipeline.zero_shot import fit_states

        tasks = [task] + ([robot_src.spec["task"]] if robot_src.spec is not None else [])
        states = fit_states(tasks, args.fit_states, reset_seeds.fixed("fit", args.seed))
    nets, signature = stitch_policies(
        task_src.path, robot_src.path, target=(robot, task), translation=args.translate, fit_states=states
    )
    ridge = translation_ridge(nets)
    if ridge is not None:
        print(f"{args.translate} translation fitted; the actor's ridge strength {ridge:.3g}")
    if args.save:
        extra = stitch_metadata(args.task_from, args.robot_from)
        if ridge is not None:
            extra["translation_ridge"] = f"{ridge:.6g}"
        path = save_policy(output_file(args.save), nets, signature, extra=extra)
        print(f"wrote {path}")
    if args.episodes > 0:
        result = evaluate(
            (nets, signature),
            robot,
            task,
            episodes=args.episodes,
            repeats=args.repeats,
            # the zero-shot stream, the block the stage gives training seed 0 (it scores each
            # training seed's pairs on a block of their own: ps_ray.plan.zero_shot.pair_episodes)
            seed=reset_seeds.fixed("zero_shot", args.seed),
            num_envs=args.num_envs,
            verbose=True,
        )
        print(
            format_result(
                result,
                f"zero-shot ({signature.method}): task module {args.task_from}, "
                f"robot module {args.robot_from}",
            )
        )
    return 0


def cmd_demo(args: argparse.Namespace) -> int:
    from ps_ray.stitching.example import ExampleZoo, demo_lines, run_demo

    zoo = ExampleZoo.load(args.zoo)  # every file verified before it is read
    print("\n".join(demo_lines(zoo, run_demo(zoo))))
    return 0


def cmd_bench(args: argparse.Namespace) -> int:
    import importlib

    importlib.import_module(f"ps_ray.bench.{args.what}").main(args.options)
    return 0


# what goes on after Ctrl-C (Tune stops a stage's trials cleanly; their checkpoints are kept)
RESUMED_BY = {
    **dict.fromkeys(("train", "grid", "run"), "the same command resumes"),
    **dict.fromkeys(("sweep", "zero-shot", "few-shot"), "the same command with --resume finishes it"),
}


def main(argv: list[str] | None = None) -> int:
    args = build_parser(__doc__).parse_args(argv)
    if getattr(args, "verbose", False):
        from ps_ray.store.terminal import VERBOSE_ENV

        os.environ[VERBOSE_ENV] = "1"  # Tune's tables and Ray's warnings on the terminal
    try:
        return {
            "train": cmd_train,
            "grid": cmd_grid,
            "sweep": cmd_sweep,
            "zero-shot": cmd_zero_shot,
            "few-shot": cmd_few_shot,
            "run": cmd_run,
            "report": cmd_report,
            "render": cmd_render,
            "bench": cmd_bench,
            "stitch": cmd_stitch,
            "demo": cmd_demo,
            "list": cmd_list,
        }[args.command](args)
    except (UserError, json.JSONDecodeError) as e:  # bad input: one line; any other error is a bug
        print(f"ps-ray {args.command}: error: {e}", file=sys.stderr)
        return 2
    except (StageInterrupted, KeyboardInterrupt) as e:  # stopped by its user: no traceback
        said = str(e) if isinstance(e, StageInterrupted) else "interrupted"
        resume = f"; {RESUMED_BY[args.command]}" if args.command in RESUMED_BY else ""
        print(f"ps-ray {args.command}: {said}{resume}", file=sys.stderr)
        return 130
    except StageError as e:  # trials failed: the first error's last line, the rest is in Tune's logs
        lines = str(e).strip().splitlines()
        print(
            f"ps-ray {args.command}: error: {lines[0]} ... {lines[-1]}"
            if len(lines) > 1
            else f"ps-ray {args.command}: error: {lines[0]}",
            file=sys.stderr,
        )
        return 1
