"""`ps-ray` command line. Bad input exits non-zero with one line naming the bad value."""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys
import time
from pathlib import Path

from ps_ray.config import SpecError, TrainSpec
from ps_ray.lock import folder_lock
from ps_ray.sweep import StageError


def _train_parser(sub) -> None:
    p = sub.add_parser("train", help="train one policy (SAC + HER on RLlib); re-running resumes")
    defaults = TrainSpec()
    for f in dataclasses.fields(TrainSpec):
        if f.name in ("robot", "task"):
            p.add_argument(
                f"--{f.name}",
                default=getattr(defaults, f.name),
                help=f"built-in name or a JSON mapping (default {getattr(defaults, f.name)})",
            )
            continue
        kind = next((t for t in (float, int, str) if t.__name__ in str(f.type)), str)
        p.add_argument(
            f"--{f.name.replace('_', '-')}", dest=f.name, type=kind, default=getattr(defaults, f.name)
        )
    p.add_argument(
        "--run-dir",
        default=None,
        help="where checkpoints, policy and metrics go (default runs/<method>-<robot>-...)",
    )
    p.add_argument("--quiet", action="store_true")


def _bench_parser(sub) -> None:
    p = sub.add_parser("bench", help="print speed figures")
    p.add_argument("what", choices=["env", "her", "train", "learn", "tracking", "evaluate", "rates"])
    p.add_argument("options", nargs=argparse.REMAINDER, help="passed to the benchmark (see --help)")


def _verbose_flag(p) -> None:
    help_text = "Tune's tables and Ray's warnings on the terminal (default: a log file)"
    p.add_argument("--verbose", action="store_true", help=help_text)


def _sweep_parser(sub) -> None:
    p = sub.add_parser("sweep", help="run a sweep YAML's training trials on Ray Tune")
    _verbose_flag(p)
    p.add_argument("sweep", help="path to a sweep YAML, e.g. sweeps/smoke.yaml")
    p.add_argument(
        "--resume", action="store_true", help="finish only the missing trials of an interrupted sweep"
    )
    p.add_argument("--storage", default=None, help="override the spec's storage directory")
    p.add_argument("--tracking-uri", default=None, help="override the MLflow tracking URI")
    p.add_argument(
        "--check", action="store_true", help="validate the spec, list trials, project the cost; run nothing"
    )
    p.add_argument("--cores", type=int, default=64, help="cluster size for the --check wall-time projection")


def _zero_shot_parser(sub) -> None:
    p = sub.add_parser("zero-shot", help="evaluate every stitched pair of a trained sweep (Tune)")
    _verbose_flag(p)
    p.add_argument("sweep", help="the sweep YAML whose trained policies are stitched")
    p.add_argument("--methods", nargs="+", default=None, help="default: the spec's zero_shot.methods")
    p.add_argument("--episodes", type=int, default=None, help="default: the spec's (200)")
    p.add_argument("--repeats", type=int, default=None, help="default: the spec's (5)")
    p.add_argument("--seed", type=int, default=None, help="first evaluation seed")
    p.add_argument("--resume", action="store_true", help="finish an interrupted matrix")
    p.add_argument("--storage", default=None, help="override the spec's storage directory")


def _few_shot_parser(sub) -> None:
    p = sub.add_parser("few-shot", help="fine-tune stitched policies of a sweep, beside from-scratch runs")
    _verbose_flag(p)
    p.add_argument("sweep", help="the sweep YAML whose trained policies are stitched")
    p.add_argument("--env-steps", type=int, default=None, help="fine-tuning budget per trial")
    p.add_argument(
        "--collect-steps",
        type=int,
        default=None,
        help="env steps collected before the first update (the paper: 10 epochs)",
    )
    p.add_argument("--methods", nargs="+", default=None)
    p.add_argument("--max-pairs", type=int, default=None, help="stitched pairs per method")
    p.add_argument("--resume", action="store_true")
    p.add_argument("--storage", default=None)


def _run_parser(sub) -> None:
    p = sub.add_parser(
        "run",
        help="the whole pipeline of a sweep YAML: train, zero-shot, few-shot, "
        "report (its 'stages'); finished stages are skipped",
    )
    _verbose_flag(p)
    p.add_argument("sweep", help="path to a sweep YAML, e.g. sweeps/smoke.yaml")
    p.add_argument("--storage", default=None, help="override the spec's storage directory")
    p.add_argument("--tracking-uri", default=None, help="override the MLflow tracking URI")


def _report_parser(sub) -> None:
    p = sub.add_parser("report", help="rebuild a sweep's report from its stored results")
    p.add_argument("sweep", help="a sweep YAML, or a sweep folder (<storage>/<name>)")
    p.add_argument("--storage", default=None, help="override the spec's storage directory")
    p.add_argument("--no-mlflow", action="store_true", help="write the folder only")
    p.add_argument(
        "--screenshot", default=None, help="also save a headless-Chromium screenshot of the page (PNG)"
    )


def _render_parser(sub) -> None:
    p = sub.add_parser("render", help="roll out one episode headless and save a PNG and/or GIF")
    p.add_argument("--robot", default="panda")
    p.add_argument("--task", default="reach")
    p.add_argument("--policy", default=None, help="a policy.safetensors (default: random actions)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--png", default=None)
    p.add_argument("--gif", default=None)


def _stitch_parser(sub) -> None:
    p = sub.add_parser("stitch", help="stitch a task module and a robot module; zero-shot evaluation")
    p.add_argument(
        "--task-from",
        required=True,
        help="policy file/run dir or zoo key (e.g. ps/panda/push/101) giving the task module",
    )
    p.add_argument(
        "--robot-from", required=True, help="policy file/run dir or zoo key giving the robot module"
    )
    p.add_argument(
        "--sweep",
        action="append",
        default=[],
        help="sweep directory (<storage>/<name>) to look keys up in; repeatable",
    )
    p.add_argument("--robot", default=None, help="target robot (default: the robot module's robot)")
    p.add_argument("--task", default=None, help="target task (default: the task module's task)")
    p.add_argument("--episodes", type=int, default=200, help="episodes per repeat (0: no evaluation)")
    p.add_argument("--repeats", type=int, default=5, help="repeats (mean +- std over them)")
    p.add_argument("--seed", type=int, default=0, help="first evaluation seed")
    p.add_argument("--num-envs", type=int, default=8, help="envs stepped in lockstep")
    p.add_argument("--save", default=None, help="write the stitched policy (.safetensors) here")
    p.add_argument(
        "--translate",
        default=None,
        choices=["orthogonal", "affine"],
        help="fit a latent translation from the task module's latent to the robot "
        "module's on reset task states of both sources' tasks (no env steps)",
    )
    p.add_argument(
        "--fit-states",
        type=int,
        default=128,
        help="reset task states per goal quadrant and task for --translate",
    )


def _mapping_or_name(value: str):
    return json.loads(value) if value.strip().startswith("{") else value


def cmd_train(args: argparse.Namespace) -> int:
    from ps_ray.train import train

    fields = {f.name: getattr(args, f.name) for f in dataclasses.fields(TrainSpec)}
    fields["robot"], fields["task"] = _mapping_or_name(args.robot), _mapping_or_name(args.task)
    spec = TrainSpec.from_mapping(fields)
    run_dir = Path(args.run_dir or Path("runs") / spec.slug())
    train(spec, run_dir, progress=not args.quiet)
    return 0


def cmd_sweep(args: argparse.Namespace) -> int:
    spec = _load(args)
    trials = spec.trials()
    print(f"sweep {spec.name!r}: {len(trials)} training trials")
    if args.check:
        from ps_ray.cost import describe, project

        for trial in trials:
            print(f"  {trial.label()}  {trial.env_steps} env steps")
        print("\n".join(describe(project(spec, cores_on=args.cores))))
        return 0
    from ps_ray.sweep import run_sweep, sweep_dir

    with folder_lock(sweep_dir(spec), "sweep"):
        results = run_sweep(spec, resume=args.resume)
    errors = [r for r in results if r.error]
    print(
        f"sweep {spec.name!r}: {len(results) - len(errors)}/{len(results)} trials finished; "
        f"results in {sweep_dir(spec)}"
    )
    return 1 if errors else 0


def _load(args: argparse.Namespace):
    """The sweep spec named on the command line, with --storage/--tracking-uri applied."""
    from ps_ray.config import load_sweep

    path = Path(args.sweep)
    if path.is_dir():  # a sweep folder: its resolved spec, stored where the folder is
        from ps_ray.layout import SweepLayout

        spec_file = SweepLayout(path).spec_file
        if not spec_file.exists():
            raise ValueError(f"{path}: not a sweep folder (no {spec_file.name})")
        spec = dataclasses.replace(load_sweep(spec_file), storage=str(path.resolve().parent))
        if spec.name != path.resolve().name:
            raise ValueError(
                f"{path}: holds sweep {spec.name!r}; a sweep folder must keep its "
                f"sweep's name (rename it back to {spec.name!r})"
            )
    else:
        spec = load_sweep(path)
    overrides = {
        k: v
        for k, v in (("storage", args.storage), ("tracking_uri", getattr(args, "tracking_uri", None)))
        if v
    }
    return dataclasses.replace(spec, **overrides) if overrides else spec


def _sweep_lock(spec):
    """Held for the whole command: a second driver on the same sweep is refused in one line."""
    from ps_ray.sweep import sweep_dir

    return folder_lock(sweep_dir(spec), "sweep")


def _given(args: argparse.Namespace, *names: str) -> dict:
    out = {n: getattr(args, n) for n in names if getattr(args, n) is not None}
    if "methods" in out:
        out["methods"] = tuple(out["methods"])
    return out


def cmd_zero_shot(args: argparse.Namespace) -> int:
    from ps_ray.zero_shot import run_zero_shot, summary

    spec = _load(args)
    with _sweep_lock(spec):
        table = run_zero_shot(
            spec, resume=args.resume, **_given(args, "methods", "episodes", "repeats", "seed")
        )
    columns = ["method", "label", "success_mean", "success_std", "touching_mean", "touching_std"]
    print(table[columns].to_string(index=False, float_format=lambda x: f"{x:.2f}"))
    print(summary(table).to_string(float_format=lambda x: f"{x:.2f}"))
    return 0


def cmd_few_shot(args: argparse.Namespace) -> int:
    from ps_ray.few_shot import curves, run_few_shot

    spec = _load(args)
    with _sweep_lock(spec):
        results = run_few_shot(
            spec, resume=args.resume, **_given(args, "env_steps", "collect_steps", "methods", "max_pairs")
        )
    for key, points in sorted(curves(results).items()):
        print(key, " ".join(f"{steps}:{success:.2f}" for steps, success in points))
    return 1 if any(r.error for r in results) else 0


def cmd_run(args: argparse.Namespace) -> int:
    from ps_ray.cost import budget_note, project
    from ps_ray.pipeline import run_pipeline
    from ps_ray.sweep import sweep_dir
    from ps_ray.tracking import default_tracking_uri

    spec = _load(args)
    started = time.time()
    print(f"sweep {spec.name!r}: stages {', '.join(spec.stages)}; results in {sweep_dir(spec)}")
    projection = project(spec)
    print(
        f"sweep {spec.name!r}: projected {projection.core_s / 3600:.2f} core-hours, about "
        f"{projection.wall_s_here / 60:.0f} min on this machine ({projection.rates.source})"
    )
    with _sweep_lock(spec):
        summaries = run_pipeline(spec)
    print(f"sweep {spec.name!r}: all stages done in {(time.time() - started) / 60:.1f} min")
    if "report" in summaries:
        print(f"report: {sweep_dir(spec) / 'report' / 'index.html'}")
    uri = spec.tracking_uri or default_tracking_uri(sweep_dir(spec))
    print(f"MLflow: .venv/bin/mlflow ui --backend-store-uri {uri}")
    note = budget_note(spec)
    if note:
        print(f"note: {note}")
    return 0


def cmd_report(args: argparse.Namespace) -> int:
    from ps_ray.analysis.report import build_report

    spec = _load(args)
    with _sweep_lock(spec):
        page = build_report(spec, log_to_mlflow=not args.no_mlflow)
    print(f"report: {page}")
    if args.screenshot:
        from ps_ray.analysis.browser import screenshot

        print(f"screenshot: {screenshot(page, args.screenshot)}")
    return 0


def cmd_render(args: argparse.Namespace) -> int:
    from ps_ray.envs.render import record
    from ps_ray.policy import GreedyPolicy

    if args.png is None and args.gif is None:
        raise ValueError("nothing to write: give --png and/or --gif")
    policy = GreedyPolicy.from_file(args.policy) if args.policy else None
    for path in (args.png, args.gif):
        if path:
            Path(path).parent.mkdir(parents=True, exist_ok=True)
    record(
        _mapping_or_name(args.robot),
        _mapping_or_name(args.task),
        policy,
        seed=args.seed,
        png=args.png,
        gif=args.gif,
    )
    print(f"wrote {' and '.join(p for p in (args.png, args.gif) if p)}")
    return 0


def cmd_stitch(args: argparse.Namespace) -> int:
    from ps_ray.evaluate import evaluate, format_result
    from ps_ray.stitch import resolve_source, resolve_target, stitch_metadata, stitch_policies
    from ps_ray.weights import save_policy
    from ps_ray.zoo import ModuleZoo

    if args.episodes < 0:
        raise ValueError(f"--episodes must be >= 0, got {args.episodes}")
    zoo = ModuleZoo.from_sweep(*args.sweep) if args.sweep else None
    task_src, robot_src = resolve_source(args.task_from, zoo), resolve_source(args.robot_from, zoo)
    robot, task = resolve_target(
        task_src,
        robot_src,
        robot=args.robot and _mapping_or_name(args.robot),
        task=args.task and _mapping_or_name(args.task),
    )
    states = None
    if args.translate:
        from ps_ray.zero_shot import fit_states

        if args.fit_states <= 0:
            raise ValueError(f"--fit-states must be positive, got {args.fit_states}")
        tasks = [task] + ([robot_src.spec["task"]] if robot_src.spec is not None else [])
        states = fit_states(tasks, args.fit_states, args.seed)
    nets, signature = stitch_policies(
        task_src.path, robot_src.path, target=(robot, task), translation=args.translate, fit_states=states
    )
    if args.save:
        path = save_policy(args.save, nets, signature, extra=stitch_metadata(args.task_from, args.robot_from))
        print(f"wrote {path}")
    if args.episodes > 0:
        result = evaluate(
            (nets, signature),
            robot,
            task,
            episodes=args.episodes,
            repeats=args.repeats,
            seed=args.seed,
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


def cmd_bench(args: argparse.Namespace) -> int:
    import importlib

    importlib.import_module(f"ps_ray.bench.{args.what}").main(args.options)
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="ps-ray", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)
    _train_parser(sub)
    _sweep_parser(sub)
    _zero_shot_parser(sub)
    _few_shot_parser(sub)
    _render_parser(sub)
    _bench_parser(sub)
    _stitch_parser(sub)
    _run_parser(sub)
    _report_parser(sub)
    args = parser.parse_args(argv)
    if getattr(args, "verbose", False):
        from ps_ray.progress import VERBOSE_ENV

        os.environ[VERBOSE_ENV] = "1"  # Tune's tables and Ray's warnings on the terminal
    try:
        return {
            "train": cmd_train,
            "sweep": cmd_sweep,
            "zero-shot": cmd_zero_shot,
            "few-shot": cmd_few_shot,
            "run": cmd_run,
            "report": cmd_report,
            "render": cmd_render,
            "bench": cmd_bench,
            "stitch": cmd_stitch,
        }[args.command](args)
    except (SpecError, ValueError, json.JSONDecodeError) as e:
        print(f"ps-ray {args.command}: error: {e}", file=sys.stderr)
        return 2
    except StageError as e:  # trials failed: the first error's last line, the rest is in Tune's logs
        lines = str(e).strip().splitlines()
        print(
            f"ps-ray {args.command}: error: {lines[0]} ... {lines[-1]}"
            if len(lines) > 1
            else f"ps-ray {args.command}: error: {lines[0]}",
            file=sys.stderr,
        )
        return 1


if __name__ == "__main__":
    sys.exit(main())
