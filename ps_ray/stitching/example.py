"""The example zoo shipped with ps_ray (``ps_ray/stitching/example/``) and ``ps-ray demo``: two
modules of a co-trained grid of the marker family stitched into a policy for the one robot-task
pair the grid never trained, scored beside its controls on the confirmation study's episodes, in
under a minute and with no training.

The zoo's manifest (``zoo.json``) names each file's SHA-256, what it was trained on and the sweep,
seed and commit that wrote it; every file is verified before it is read, so a corrupt or foreign
file is refused in one line. The figures the study recorded for these files are in the manifest
too, and the demo prints them beside its own."""

from __future__ import annotations

import hashlib
import json
import time
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ps_ray.errors import UserError
from ps_ray.specs import reset_seeds
from ps_ray.store.formats import EXAMPLE_ZOO

EXAMPLE_DIR = Path(__file__).parent / "example"
MANIFEST = "zoo.json"
FORMAT = EXAMPLE_ZOO.id
ROLES = ("task_module", "robot_module", "oracle")
# The rows of the demo's table: (key of its success, what it is)
ROWS = (
    ("stitched", "stitched: task module + robot module (label-free)"),
    ("robot_source", "robot module's source, as it is"),
    ("task_source", "task module's source, as it is"),
    ("chance", "chance (the better of random actions and a random point)"),
    ("task_blind_floor", "task-blind floor (either marker, in expectation)"),
    ("oracle", "oracle: trained on the target pair (reads it)"),
    ("ceiling", "ceiling: robot module's source told the task (reads it)"),
)


@dataclass(frozen=True)
class ExampleZoo:
    root: Path
    manifest: Mapping[str, Any]

    @classmethod
    def load(cls, root: str | Path = EXAMPLE_DIR) -> ExampleZoo:
        """The zoo in ``root``, every file checked against its manifest's SHA-256 first."""
        root = Path(root)
        try:
            manifest = json.loads((root / MANIFEST).read_text())
        except (OSError, json.JSONDecodeError) as e:
            raise UserError(f"{root / MANIFEST}: not an example zoo manifest ({e})") from None
        if not isinstance(manifest, dict) or not EXAMPLE_ZOO.reads(manifest.get("format")):
            raise UserError(f"{root / MANIFEST}: not an example zoo manifest (format {FORMAT} expected)")
        for role in ROLES:
            entry = (manifest.get("modules") or {}).get(role)
            if not isinstance(entry, dict) or not {"file", "sha256"} <= set(entry):
                raise UserError(f"{root / MANIFEST}: no file and SHA-256 for the {role}")
            path = root / entry["file"]
            if not path.is_file():
                raise UserError(f"{path}: missing from the example zoo")
            found = hashlib.sha256(path.read_bytes()).hexdigest()
            if found != entry["sha256"]:
                raise UserError(
                    f"{path}: SHA-256 {found[:12]}... is not the manifest's {entry['sha256'][:12]}...: "
                    f"a corrupt or foreign file; restore it (git checkout {path.name})"
                )
        return cls(root, manifest)

    def path(self, role: str) -> Path:
        return self.root / self.manifest["modules"][role]["file"]

    def trained_on(self, path: Path) -> dict[str, Any] | None:
        """The robot and task the zoo's file ``path`` was trained on (None: not one of its files)."""
        for entry in self.manifest["modules"].values():
            if self.root / entry["file"] == path and isinstance(entry.get("trained_on"), dict):
                return dict(entry["trained_on"])
        return None

    @property
    def target(self) -> tuple[str, str]:
        return self.manifest["target"]["robot"], self.manifest["target"]["task"]

    @property
    def episodes(self) -> dict[str, int]:
        """``evaluate``'s episodes, repeats and first reset seed: the block of the zero-shot stream
        the study scored these files on (before each training seed had a block of its own)."""
        given = self.manifest["episodes"]
        seed = reset_seeds.fixed("zero_shot", given["zero_shot_seed"])
        return {"episodes": given["episodes"], "repeats": given["repeats"], "seed": seed}


def run_demo(zoo: ExampleZoo) -> dict[str, Any]:
    """Stitch the zoo's task module and robot module, and score the stitch, each control and the
    ceiling (the robot module's source told the task, :mod:`ps_ray.stitching.told`) on the same
    episodes: greedy success per row of :data:`ROWS`, the transfer gain over the best control,
    the episodes' count and the wall time."""
    from ps_ray.specs.names import EnvPart
    from ps_ray.stitching.chance import chance
    from ps_ray.stitching.evaluate import as_action_fn, evaluate
    from ps_ray.stitching.stitch import stitch_policies
    from ps_ray.stitching.told import TellTask

    start = time.time()
    robot, task = zoo.target
    settings = zoo.episodes
    stitched = stitch_policies(zoo.path("task_module"), zoo.path("robot_module"))
    scored = {"stitched": evaluate(stitched, robot, task, **settings)}
    for key, role in (("robot_source", "robot_module"), ("task_source", "task_module"), ("oracle", "oracle")):
        scored[key] = evaluate(zoo.path(role), robot, task, **settings)
    robot_task = zoo.manifest["modules"]["robot_module"]["trained_on"]["task"]
    told = TellTask(as_action_fn(zoo.path("robot_module"))[0], EnvPart(task), EnvPart(robot_task))
    scored["ceiling"] = evaluate(told, robot, task, **settings)  # what a perfect map would reach
    digests = {result["episodes_digest"] for result in scored.values()}
    levels = chance(robot, task, settings)
    if digests != {levels["episodes_digest"]}:  # a bug, never bad input
        raise RuntimeError("the demo's policies ran on different episodes")
    success = {key: result["success_mean"] for key, result in scored.items()}
    success.update(chance=levels["chance_success"], task_blind_floor=levels["task_blind_success"])
    controls = ("robot_source", "task_source", "chance", "task_blind_floor")
    best = max(controls, key=lambda key: success[key])
    return {
        "success": success,
        "wrong_target": scored["stitched"]["wrong_target_mean"],
        "best_control": best,
        "gain": success["stitched"] - success[best],
        "episodes": settings["episodes"] * settings["repeats"],
        "wall_s": time.time() - start,
    }


def demo_lines(zoo: ExampleZoo, result: Mapping[str, Any]) -> list[str]:
    """What ``ps-ray demo`` prints: where the modules come from, the table beside the study's
    figures for these files, and what it shows."""
    modules, provenance = zoo.manifest["modules"], zoo.manifest["provenance"]
    recorded = zoo.manifest["recorded"]["this_seed"]
    robot, task = zoo.target

    def pair(entry: Mapping[str, str]) -> str:
        return f"{entry['trained_on']['robot']}/{entry['trained_on']['task']}"

    lines = [
        f"example zoo: {len(ROLES)} policy files verified (SHA-256), written by "
        f"{provenance['sweep']} (seed {provenance['seed']}, commit {provenance['commit'][:7]})",
        f"stitch: the task module trained on {pair(modules['task_module'])} + the robot module trained "
        f"on {pair(modules['robot_module'])} -> {robot}/{task}, a pair no module was trained on",
        f"{result['episodes']} episodes, the same for every row ({result['wall_s']:.0f} s)",
        "",
        f"  {'policy':<58} {'success':>7}  {'study':>5}",
    ]
    for key, words in ROWS:
        lines.append(f"  {words:<58} {result['success'][key]:>7.2f}  {recorded[key]:>5.2f}")
    best = dict(ROWS)[result["best_control"]].split(" (")[0]
    lines += [
        "",
        f"transfer gain: {result['gain']:+.2f} over the best control ({best}); the stitch ended at a "
        f"marker the task did not name in {result['wrong_target']:.0%} of episodes",
        f"over the study's five seeds: {zoo.manifest['recorded']['five_seeds']} ({provenance['study']})",
    ]
    return lines
