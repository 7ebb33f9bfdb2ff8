"""Policies and target envs named on the ``ps-ray stitch`` command line: a policy file, a run
folder or a key of a sweep's zoo, and the target env they imply
(:func:`ps_ray.stitching.rule.default_target`)."""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

from ps_ray.errors import UserError
from ps_ray.specs.names import EnvPart
from ps_ray.specs.train import TrainSpec
from ps_ray.stitching.rule import EnvSpec, default_target
from ps_ray.stitching.zoo import ModuleZoo
from ps_ray.store.run_layout import POLICY_FILE, SPEC_FILE


@dataclass(frozen=True)
class Resolved:
    """A policy named on the command line: its file and training spec (None if unknown)."""

    path: Path
    spec: Mapping | None


def resolve_source(ref: str, zoo: ModuleZoo | None = None) -> Resolved:
    """A policy file, a directory holding ``policy.safetensors``, or a key of ``zoo``; its training
    spec from the ``spec.json`` beside it, or from the manifest of the example zoo it is in."""
    from ps_ray.store.signature import read_signature

    path = Path(ref)
    if path.is_dir():
        path = path / POLICY_FILE
    if path.is_file():
        read_signature(path)  # a file that is not a policy is named as such, first
        spec_path = path.parent / SPEC_FILE
        if not spec_path.is_file():
            return Resolved(path, _example_spec(path))
        try:
            spec = dict(TrainSpec.upgrade(json.loads(spec_path.read_text())))
        except (json.JSONDecodeError, TypeError, ValueError, UnicodeDecodeError) as e:
            raise UserError(f"{spec_path}: unreadable training spec ({e})") from None
        missing = [key for key in ("robot", "task") if key not in spec]
        if missing:
            raise UserError(f"{spec_path}: incomplete training spec (no {missing[0]!r}); give --{missing[0]}")
        return Resolved(path, spec)
    if zoo is None:
        raise UserError(f"{ref}: no such policy file (give --sweep DIR to look keys up)")
    entry = zoo.get(ref)
    return Resolved(entry.path, entry.spec)


def _example_spec(path: Path) -> dict | None:
    """What a file of the example zoo (``ps-ray demo``'s) was trained on, from its manifest."""
    from ps_ray.stitching.example import MANIFEST, ExampleZoo

    if not (path.parent / MANIFEST).is_file():
        return None
    try:
        return ExampleZoo.load(path.parent).trained_on(path)
    except UserError:  # a manifest of something else, or a file it does not vouch for
        return None


def resolve_target(
    task_src: Resolved,
    robot_src: Resolved,
    robot: EnvPart | None = None,
    task: EnvPart | None = None,
) -> EnvSpec:
    """The target env: the given robot/task, else :func:`default_target`'s choice."""
    needs = [
        (src, what)
        for src, what, given in ((task_src, "task", task), (robot_src, "robot", robot))
        if given is None and src.spec is None
    ]
    if needs:
        src, what = needs[0]
        raise UserError(f"{src.path}: no spec.json beside it to tell the target {what}; give --{what}")
    task = EnvPart(task_src.spec["task"] if task is None else task)
    if robot is None:
        robot = default_target({"task": task}, robot_src.spec)[0]
    return EnvPart(robot), task
