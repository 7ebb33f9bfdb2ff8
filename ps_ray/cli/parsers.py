"""The arguments of every `ps-ray` command (the commands themselves are in :mod:`ps_ray.cli`)."""

from __future__ import annotations

import argparse
import dataclasses
from enum import Enum

from ps_ray.cli.args import Parser, positive_int, seed_int
from ps_ray.specs.engine import flag_kwargs, type_hints
from ps_ray.specs.names import LATENT_TRANSLATIONS
from ps_ray.specs.sweep import SUB_SPECS
from ps_ray.specs.train import TrainSpec


def build_parser(description: str | None) -> argparse.ArgumentParser:
    from importlib.metadata import version

    parser = Parser(prog="ps-ray", description=description)
    parser.add_argument("--version", action="version", version=f"ps-ray {version('ps_ray')}")
    sub = parser.add_subparsers(dest="command", required=True)
    for add in (
        _demo_parser,
        _train_parser,
        _grid_parser,
        _sweep_parser,
        _zero_shot_parser,
        _few_shot_parser,
        _render_parser,
        _bench_parser,
        _stitch_parser,
        _run_parser,
        _report_parser,
        _list_parser,
    ):
        add(sub)
    return parser


def _train_parser(sub) -> None:
    p = sub.add_parser("train", help="train one policy (SAC + HER on RLlib); re-running resumes")
    _train_spec_flags(p)
    p.add_argument(
        "--run-dir",
        default=None,
        help="where checkpoints, policy and metrics go (default runs/<method>-<robot>-...)",
    )
    p.add_argument("--quiet", action="store_true", help="no progress lines, only the final summary")
    p.add_argument(
        "--verbose",
        action="store_true",
        help="Ray's and RLlib's messages on the terminal (default: <run dir>/logs/ray.log)",
    )
    p.add_argument(
        "--compile",
        action="store_true",
        help="compile the learner's forward pass (torch.compile; measured slower on CPU cores, docs/cost.md)",
    )


def _grid_parser(sub) -> None:
    p = sub.add_parser(
        "grid",
        help="co-train the task and robot modules of a robot x task grid (Devin et al.); re-running resumes",
    )
    p.add_argument("--robots", nargs="+", required=True, help="the grid's robots (names or JSON mappings)")
    p.add_argument("--tasks", nargs="+", required=True, help="the grid's tasks (names or JSON mappings)")
    p.add_argument(
        "--held-out",
        nargs="*",
        default=[],
        metavar="ROBOT/TASK",
        help="cells never trained, to be stitched zero-shot (e.g. panda_far/reach_blue)",
    )
    _train_spec_flags(p, skip=("robot", "task", "init_policy", "anchors"))
    p.add_argument("--run-dir", required=True, help="where checkpoints, cell policies and metrics go")
    p.add_argument("--quiet", action="store_true", help="no progress lines, only the final summary")
    p.add_argument(
        "--verbose",
        action="store_true",
        help="Ray's and RLlib's messages on the terminal (default: <run dir>/logs/ray.log)",
    )


def _train_spec_flags(p, skip: tuple[str, ...] = ()) -> None:
    """A flag per TrainSpec field (its help text is the field's doc), but ``skip``."""
    defaults, hints = TrainSpec(), type_hints(TrainSpec)
    for f in dataclasses.fields(TrainSpec):
        if f.name in skip:
            continue
        help = f"{f.metadata['help']} (default {getattr(defaults, f.name)})"
        if f.name in ("robot", "task"):
            p.add_argument(f"--{f.name}", default=getattr(defaults, f.name).text, help=help)
            continue
        flag = f"--{f.name.replace('_', '-')}"
        p.add_argument(
            flag, dest=f.name, default=getattr(defaults, f.name), help=help, **flag_kwargs(hints[f.name])
        )


# The settings of a stage that its own command takes as flags, each over the sweep file's value
STAGE_FLAGS = {
    "zero_shot": ("methods", "episodes", "repeats", "seed", "pairs", "pairs_per_trial"),
    "few_shot": (
        "env_steps",
        "collect_steps",
        "methods",
        "max_pairs",
        "pairs_per_seed",
        "critic_warmup_updates",
    ),
}


def _stage_flags(p, stage: str) -> None:
    """A flag per setting in :data:`STAGE_FLAGS`, read as the settings' spec field reads it."""
    settings = SUB_SPECS[stage]
    hints, defaults = type_hints(settings), settings()
    for name in STAGE_FLAGS[stage]:
        default = getattr(defaults, name)
        said = (
            "the sweep's methods"
            if name == "methods"
            else default.value
            if isinstance(default, Enum)
            else default
        )
        p.add_argument(
            f"--{name.replace('_', '-')}",
            dest=name,
            default=None,
            help=f"{stage}.{name} for this run (default: the sweep file's, else {said})",
            **flag_kwargs(hints[name]),
        )


# ps-ray bench WHAT: each a module of ps_ray.bench, and what it measures
BENCHMARKS = {
    "env": "env steps/s per task beside a bare PyBullet loop",
    "her": "hindsight replay writes and samples per second",
    "train": "the RLlib trainer beside a bare-torch loop doing the same work",
    "update": "one SAC gradient update per method (--devices cuda on a GPU)",
    "gpu": "a GPU host's one call: populations equal solo learners (eager, one CUDA graph), cost vs K",
    "grid": "one co-trained grid update beside bare torch",
    "learn": "env steps to a greedy success target per method, over seeds",
    "tracking": "the driver-side cost of MLflow tracking per Tune result",
    "evaluate": "zero-shot evaluation speed beside the env's own step rate",
    "rates": "measure and cache the per-core rates --check prices with",
    "state": "what crash safety costs: atomic writes, locks, sealing checkpoints",
    "outcomes": "how many outcome scenes an affine@outcome fit needs, and their cost",
}


def _bench_parser(sub) -> None:
    p = sub.add_parser(
        "bench",
        help="print speed figures",
        epilog="benchmarks:\n" + "\n".join(f"  {name:<9} {purpose}" for name, purpose in BENCHMARKS.items()),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("what", choices=list(BENCHMARKS), metavar="WHAT", help="one of the benchmarks below")
    p.add_argument("options", nargs=argparse.REMAINDER, help="passed to the benchmark (see --help)")


def _sweep_arg(p, help_text: str) -> None:
    """The SWEEP positional, and ``--set`` overrides of its keys."""
    p.add_argument("sweep", help=help_text)
    p.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="override a key of the sweep file (dotted, the value as YAML), e.g. --set zero_shot.episodes=10",
    )


def _verbose_flag(p) -> None:
    help_text = "Tune's tables and Ray's warnings on the terminal (default: a log file)"
    p.add_argument("--verbose", action="store_true", help=help_text)


def _sweep_parser(sub) -> None:
    p = sub.add_parser("sweep", help="run a sweep YAML's training trials on Ray Tune")
    _verbose_flag(p)
    _sweep_arg(p, "path to a sweep YAML, e.g. sweeps/smoke.yaml")
    p.add_argument(
        "--resume", action="store_true", help="finish only the missing trials of an interrupted sweep"
    )
    p.add_argument("--storage", default=None, help="override the spec's storage directory")
    p.add_argument("--tracking-uri", default=None, help="override the MLflow tracking URI")
    _check_flags(p)


def _check_flags(p) -> None:
    p.add_argument(
        "--check",
        action="store_true",
        help="validate the spec, list trials, project the cost of every stage; run nothing",
    )
    p.add_argument(
        "--cores",
        type=positive_int,
        default=64,
        help="ideal cores (one trial each) for --check; cluster.yaml's kinds are projected too",
    )


def _zero_shot_parser(sub) -> None:
    p = sub.add_parser("zero-shot", help="evaluate every stitched pair of a trained sweep (Tune)")
    _verbose_flag(p)
    _sweep_arg(p, "the sweep YAML whose trained policies are stitched")
    _stage_flags(p, "zero_shot")
    p.add_argument("--resume", action="store_true", help="finish an interrupted matrix")
    p.add_argument("--storage", default=None, help="override the spec's storage directory")


def _few_shot_parser(sub) -> None:
    p = sub.add_parser("few-shot", help="fine-tune stitched policies of a sweep, beside from-scratch runs")
    _verbose_flag(p)
    _sweep_arg(p, "the sweep YAML whose trained policies are stitched")
    _stage_flags(p, "few_shot")
    p.add_argument(
        "--resume", action="store_true", help="finish only the missing trials of an interrupted stage"
    )
    p.add_argument("--storage", default=None, help="override the spec's storage directory")


def _demo_parser(sub) -> None:
    from ps_ray.stitching.example import EXAMPLE_DIR

    p = sub.add_parser(
        "demo",
        help="stitch the shipped example modules into a policy for a robot-task pair they were not "
        "trained on and score it beside its controls (under a minute, no training)",
    )
    p.add_argument("--zoo", default=str(EXAMPLE_DIR), help="an example zoo folder (default: the shipped one)")


def _run_parser(sub) -> None:
    p = sub.add_parser(
        "run",
        help="the whole pipeline of a sweep YAML: train, zero-shot, few-shot, "
        "report (its 'stages'); finished stages are skipped",
    )
    _verbose_flag(p)
    _sweep_arg(p, "path to a sweep YAML, e.g. sweeps/smoke.yaml")
    p.add_argument("--storage", default=None, help="override the spec's storage directory")
    p.add_argument("--tracking-uri", default=None, help="override the MLflow tracking URI")
    _check_flags(p)


def _list_parser(sub) -> None:
    sub.add_parser("list", help="the robots, tasks, methods, translations and shipped sweeps, one line each")


def _report_parser(sub) -> None:
    p = sub.add_parser("report", help="rebuild a sweep's report from its stored results")
    _sweep_arg(p, "a sweep YAML, or a sweep folder (<storage>/<name>)")
    p.add_argument("--storage", default=None, help="override the spec's storage directory")
    p.add_argument("--no-mlflow", action="store_true", help="write the folder only")
    p.add_argument(
        "--screenshot", default=None, help="also save a headless-Chromium screenshot of the page (PNG)"
    )


def _render_parser(sub) -> None:
    p = sub.add_parser("render", help="roll out one episode headless and save a PNG and/or GIF")
    p.add_argument("--robot", default="panda", help="built-in robot name or a JSON mapping")
    p.add_argument("--task", default="reach", help="built-in task name or a JSON mapping")
    p.add_argument("--policy", default=None, help="a policy.safetensors (default: random actions)")
    p.add_argument("--seed", type=seed_int, default=0, help="the episode's reset seed")
    p.add_argument("--png", default=None, help="save the last frame here")
    p.add_argument("--gif", default=None, help="save the episode as an animated GIF here")


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
    p.add_argument("--repeats", type=positive_int, default=5, help="repeats (mean +- std over them)")
    p.add_argument(
        "--seed", type=seed_int, default=0, help="the episodes' seed in the zero-shot reset-seed block"
    )
    p.add_argument("--num-envs", type=positive_int, default=8, help="envs stepped in lockstep")
    p.add_argument("--save", default=None, help="write the stitched policy (.safetensors) here")
    p.add_argument(
        "--translate",
        default=None,
        choices=list(LATENT_TRANSLATIONS),
        help="fit a latent translation from the task module's latent to the robot "
        "module's on reset task states of both sources' tasks (no env steps; affine: ridge, "
        "its strength cross-validated; affine_lstsq: plain least squares, the old fit)",
    )
    p.add_argument(
        "--fit-states",
        type=positive_int,
        default=128,
        help="reset task states per goal quadrant and task for --translate",
    )
