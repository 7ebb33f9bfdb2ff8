"""Bad input at the command line, as a user would give it: every case exits 2 with one line on
stderr naming the bad value, and writes nothing (no run or sweep folder, no output file)."""

from __future__ import annotations

import json
import pickle
import subprocess
import sys
from pathlib import Path

import pytest

from ps_ray.nets.from_signature import signature_of
from ps_ray.nets.policy_file import save_policy
from ps_ray.nets.sac import build_sac_nets
from ps_ray.stitching.stitch import env_dims


class _Evil:
    def __reduce__(self):
        return (exec, ("open('PICKLE_RAN', 'w')",))


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """A reach policy (ablation, untrained), a garbage file, a pickle and a sweep YAML."""
    root = tmp_path_factory.mktemp("inputs")
    nets = build_sac_nets("ablation", env_dims("panda", "reach"), interface_dim=8, hidden=16)
    save_policy(root / "reach.safetensors", nets, signature_of(nets, "ablation", 8, 16))
    (root / "garbage.safetensors").write_bytes(bytes(range(256)) * 2)
    (root / "evil.npy").write_bytes(pickle.dumps(_Evil()))
    (root / "incomplete_run").mkdir()
    (root / "incomplete_run" / "policy.safetensors").write_bytes((root / "reach.safetensors").read_bytes())
    (root / "incomplete_run" / "spec.json").write_text('{"seed": 1}')
    for name, content in (("binary", bytes(range(256))), ("list", b"[1, 2]")):
        (root / f"{name}_run").mkdir()
        (root / f"{name}_run" / "spec.json").write_bytes(content)
    for name, extra in (
        ("no_anchors", "anchors: {file: /nonexistent/states.npz}\n"),
        ("bad_start", f"train: {{init_policy: {root / 'garbage.safetensors'}}}\n"),
    ):
        (root / f"{name}.yaml").write_text(
            f"name: {name}\nmethods: [ablation]\nrobots: [panda]\ntasks: [reach]\nseeds: [1]\n"
            f"storage: {root / 'sweeps'}\n{extra}"
        )
    (root / "typed.yaml").write_text(
        "name: typed\nmethods: [ablation]\nrobots: [panda]\ntasks: [{name: reach_red, min_separation: x}]\n"
        f"seeds: [1]\nstorage: {root / 'sweeps'}\n"
    )
    (root / "no_train.yaml").write_text(
        "name: no_train\nmethods: [ablation]\nrobots: [panda, panda_far]\ntasks: [reach_red, reach_blue]\n"
        f"seeds: [1]\nstages: [grid, zero_shot]\nstorage: {root / 'sweeps'}\n"
    )
    (root / "sweep.yaml").write_text(
        f"name: never\nmethods: [ablation]\nrobots: [panda]\ntasks: [reach]\nseeds: [1]\n"
        f"storage: {root / 'sweeps'}\n"
    )
    return root


CASES = [  # (arguments, with {f} the input folder and {out} a path that must not appear; message)
    (
        "train --method ablation --interface-dim 8 --hidden 16 --init-policy {f}/garbage.safetensors "
        "--run-dir {out}",
        "garbage.safetensors: not a ps_ray policy file",
    ),
    (
        "train --method ablation --interface-dim 8 --hidden 16 --task push --init-policy "
        "{f}/reach.safetensors --run-dir {out}",
        "reach.safetensors: cannot start this run: task dim: policy 3 vs target env (panda, push) 15",
    ),
    (
        "train --method ablation --hidden 32 --init-policy {f}/reach.safetensors --run-dir {out}",
        "(method, interface dim, hidden) ('ablation', 8, 16) vs ('ablation', 128, 32)",
    ),
    ("train --anchors {f}/missing.npz --run-dir {out}", "missing.npz: cannot read the file (No such file"),
    ("train --anchors {f}/evil.npy --run-dir {out}", "evil.npy: neither an .npy nor an .npz file"),
    ("train --seed -1 --run-dir {out}", "seed must be an integer 0..99999, got -1"),
    (
        "train --env nosuch:Thing-v0 --run-dir {out}",
        "--env: env 'nosuch:Thing-v0' is not a gymnasium id this Python can make (No module named 'nosuch')",
    ),
    (
        "train --eval-every -2 --run-dir {out}",
        "--eval-every: eval_every must be a non-negative integer, got -2",
    ),
    ("render --seed -1 --png {out}/x.png", "argument --seed: expected a seed in 0..4294967295, got -1"),
    (
        "stitch --task-from {f}/incomplete_run --robot-from {f}/reach.safetensors --save {out}/s.safetensors",
        "incomplete_run/spec.json: incomplete training spec (no 'robot'); give --robot",
    ),
    (
        "report {f}/sweep.yaml --screenshot {f}/garbage.safetensors/x.png",
        "garbage.safetensors is a file, not a",
    ),
    ("run {f}/sweep.yaml --tracking-uri ftp://nowhere", "tracking_uri 'ftp://nowhere': not an MLflow"),
    ("run {f}/sweep.yaml --tracking-uri {f}/mlruns", "mlruns': not an MLflow tracking store; valid: http"),
    ("sweep {f}/typed.yaml --check", "task 'reach_red' option min_separation: expected a number, got 'x'"),
    (
        "sweep {f}/sweep.yaml --check --storage {f}/garbage.safetensors/runs",
        "garbage.safetensors/runs/never: cannot write the sweep folder (",
    ),
    ("zero-shot {f}/sweep.yaml --methods ps", "method 'ps' is not trained by this sweep; valid: ablation"),
    ("zero-shot {f}/sweep.yaml", "sweeps/never: no trained sweep there; train it first"),
    ("few-shot {f}/sweep.yaml --env-steps 0", "few_shot.env_steps must be a positive integer, got 0"),
    (
        "few-shot {f}/sweep.yaml --set few_shot.translation=anchors@outcome",
        "few_shot.translation: 'anchors@outcome' is not a fitted latent map; valid: orthogonal, affine,",
    ),
    (
        "render --policy {f}/reach.safetensors --task push --png {out}",
        "reach.safetensors: cannot run here: task dim: policy 3 vs target env (panda, push) 15",
    ),
    ("train --hidden 100000 --run-dir {out}", "hidden must be at most 8192, got 100000"),
    ("train --run-dir {f}/binary_run", "binary_run/spec.json: not a ps_ray run spec (not JSON text"),
    ("train --run-dir {f}/list_run", "list_run/spec.json: not a ps_ray run spec (a JSON list)"),
    ("report {f}/sweep.yaml", "sweeps/never: no trained sweep there; train it first"),
    ("sweep {f}/no_anchors.yaml", "anchors.file: /nonexistent/states.npz: no such file"),
    ("sweep {f}/no_train.yaml", "has no train stage (stages: grid, zero_shot); ps-ray run runs them"),
    ("run {f}/bad_start.yaml", "garbage.safetensors: not a ps_ray policy file"),
    ("render --robot pandaa --png {out}/x.png", "unknown robot 'pandaa'; valid robots: panda, panda_l3"),
    ("render --png {f}/reach.safetensors/x.png", "reach.safetensors is a file, not a folder"),
    ("render --png {out}/out.txt", "out.txt: the image is written as png; valid file names end in .png"),
    ("render --gif {out}/clip.png", "clip.png: the image is written as gif; valid file names end in .gif"),
    (
        "stitch --task-from {f}/reach.safetensors --robot-from {f}/reach.safetensors --repeats 0 "
        "--save {out}/s.safetensors",
        "argument --repeats: expected a positive integer, got 0",
    ),
    (
        "stitch --task-from {f}/reach.safetensors --robot-from {f}/reach.safetensors --robot panda "
        "--task reach --episodes 0 --save {f}/garbage.safetensors/s",
        "garbage.safetensors is a file, not a folder",
    ),
    (
        "stitch --task-from {f}/reach.safetensors --robot-from {f}/reach.safetensors --episodes 0",
        "--episodes 0 without --save does nothing; give --save FILE or --episodes N > 0",
    ),
    ('train --robot {{"name":"panda","mount":"left"}} --run-dir {out}', "bad mount 'left'; valid mounts"),
    ('train --task {{"name":"reach_red","target":2}} --run-dir {out}', "bad target 2; valid targets: 0..1"),
    ("bench env --steps 0", "argument --steps: expected a positive integer, got 0"),
    ("bench her --repeats -3", "argument --repeats: expected a positive integer, got -3"),
    ("bench update --methods ps nope", "unknown method 'nope'; valid presets: ps, ps_distilled, ablation"),
    ("bench update --dims 15,8", "--dims takes TASK,ROBOT,ACTION widths, e.g. 15,8,7; got '15,8'"),
    (
        "bench learn --methods ablation nope --out {out}/b",
        "unknown method 'nope'; valid presets: ps, ps_distilled",
    ),
    ("train --method ps+norm=batch --run-dir {out}", "method 'ps+norm=batch': unknown relative norm 'batch'"),
    (
        "train --method ps+nrom=layer --run-dir {out}",
        "method 'ps+nrom=layer': unknown option 'nrom'; valid: relative, center",
    ),
    ("bench learn --methods ps --out {out}/b", "--baseline 'ablation' is not among --methods"),
    ("train --method ps_ln --run-dir {out}/r", "method 'ps_ln' is an old name; write it as 'ps+norm=layer'"),
    (
        "train --task push --hindsight marker --run-dir {out}/r",
        "hindsight 'marker' needs a task said in a marker's frame, got task 'push'; valid: reach_red",
    ),
    ("train --task push_red --hindsight scene --run-dir {out}/r", "unknown hindsight 'scene'; valid"),
]


def _case_args(files: Path, folder: Path, args: str) -> list[str]:
    return args.format(f=files, out=folder / "out").split()


@pytest.fixture(scope="module")
def outcomes(files, tmp_path_factory):
    """Every case of CASES run in one process (tests/cli_cases.py), each in a folder of its own:
    per case its exit code, its stderr and which of the paths it must not write exist."""
    root = tmp_path_factory.mktemp("cases")
    cases = []
    for i, (args, _) in enumerate(CASES):
        (folder := root / str(i)).mkdir()
        absent = [str(folder / "out"), str(files / "sweeps"), str(folder / "PICKLE_RAN")]
        cases.append({"argv": _case_args(files, folder, args), "cwd": str(folder), "absent": absent})
    (root / "cases.json").write_text(json.dumps(cases))
    proc = subprocess.run(
        [sys.executable, "-m", "tests.cli_cases", root / "cases.json", root / "results.json"],
        capture_output=True,
        text=True,
        timeout=600,
        cwd=Path(__file__).resolve().parents[1],
    )
    results = [json.loads(line) for line in (root / "results.json").read_text().splitlines()]
    assert proc.returncode == 0, f"case {len(results)} ended the process: {proc.stderr[-3000:]}"
    return [{**case, **result} for case, result in zip(cases, results, strict=True)]


@pytest.mark.e2e
@pytest.mark.parametrize(
    "case, message",
    enumerate(c[1] for c in CASES),
    ids=[c[0].split(" --")[0] + f"-{i}" for i, c in enumerate(CASES)],
)
def test_bad_input_is_one_line_exit_2_and_writes_nothing(outcomes, case, message):
    found = outcomes[case]
    stderr = found["stderr"]
    assert found["code"] == 2, stderr[-3000:]
    (line,) = stderr.strip().splitlines()  # one line, nothing else on stderr
    assert "error" in line and message in line, stderr[-3000:]
    assert "Traceback" not in stderr and "usage:" not in stderr
    assert not found["present"], f"written: {found['present']}"  # no output, no sweep, no pickle ran


@pytest.mark.e2e
def test_a_case_of_each_command_shows_alone_what_it_showed_beside_the_others(outcomes):
    """What a process prints once (at import, a warning's first time, at exit) would show in one
    shared case at most: the first case of each command, run again in a process of its own in the
    same folder, exits the same and prints the same stderr."""
    firsts = {}
    for i, (args, _) in enumerate(CASES):
        firsts.setdefault(" ".join(args.split()[: 2 if args.startswith("bench") else 1]), i)
    assert len(firsts) >= 10  # train, render, stitch, report, run, sweep, zero-shot, few-shot, benches
    for command, i in firsts.items():
        case = outcomes[i]
        proc = subprocess.run(
            [sys.executable, "-m", "ps_ray.cli", *case["argv"]],
            capture_output=True,
            text=True,
            timeout=120,
            cwd=case["cwd"],
        )
        assert (proc.returncode, proc.stderr) == (case["code"], case["stderr"]), command


@pytest.mark.e2e
def test_version_names_the_installed_package():
    from importlib.metadata import version

    proc = subprocess.run([sys.executable, "-m", "ps_ray.cli", "--version"], capture_output=True, text=True)
    assert proc.returncode == 0 and proc.stdout.strip() == f"ps-ray {version('ps_ray')}"


@pytest.mark.e2e
def test_every_command_flag_and_benchmark_has_help():
    import argparse
    import importlib.util

    from ps_ray.cli.parsers import BENCHMARKS, build_parser

    missing = []

    def walk(parser: argparse.ArgumentParser, where: str) -> None:
        for action in parser._actions:
            if isinstance(action, argparse._SubParsersAction):
                helps = {choice.dest: choice.help for choice in action._choices_actions}
                for name, sub in action.choices.items():
                    if not helps.get(name):
                        missing.append(f"{where} {name}")
                    walk(sub, f"{where} {name}")
            elif not isinstance(action, argparse._HelpAction) and not action.help:
                missing.append(f"{where} {'/'.join(action.option_strings) or action.dest}")

    walk(build_parser("ps-ray"), "ps-ray")
    assert not missing, f"without help: {', '.join(missing)}"
    assert all(importlib.util.find_spec(f"ps_ray.bench.{name}") for name in BENCHMARKS)
    bench = subprocess.run(
        [sys.executable, "-m", "ps_ray.cli", "bench", "--help"], capture_output=True, text=True
    )
    assert "outcomes  how many outcome scenes" in bench.stdout  # one line per benchmark
