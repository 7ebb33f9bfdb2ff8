"""The few-shot stage's trials: fine-tuning runs that start from stitched pairs (as they are, and
aligned by a fitted latent map; taken apart, from each half of the stitch beside a fresh other
half), from each pair's robot source as it is, and from scratch on each target."""

from __future__ import annotations

import hashlib
from collections import Counter
from pathlib import Path

from ps_ray.plan.train import anchor_file
from ps_ray.specs.modes import TrialKind
from ps_ray.specs.names import trial_key
from ps_ray.specs.stage_settings import FewShotSpec
from ps_ray.specs.sweep import SweepSpec
from ps_ray.specs.train import TrainSpec
from ps_ray.specs.trial import HALVES, TrainTrial
from ps_ray.stitching.pairs import StitchedPair
from ps_ray.stitching.zoo import ModuleZoo
from ps_ray.store.layout import sweep_layout


def selected_pairs(pairs: list[StitchedPair], settings: FewShotSpec) -> list[StitchedPair]:
    """The pairs few-shot starts from, of the evaluated same-seed pairs without a translation
    (in the matrix's order): per method, the first ``max_pairs``, at most ``pairs_per_seed`` of
    each seed."""
    selected, taken, per_seed = [], Counter(), Counter()
    for pair in pairs:
        seed_key = (pair.method, pair.seed)
        if settings.max_pairs is not None and taken[pair.method] >= settings.max_pairs:
            continue
        if settings.pairs_per_seed is not None and per_seed[seed_key] >= settings.pairs_per_seed:
            continue
        taken[pair.method] += 1
        per_seed[seed_key] += 1
        selected.append(pair)
    return selected


def starts(settings: FewShotSpec) -> tuple[str, ...]:
    """The starts made from each selected pair: with ``stitched`` the stitch as it is, with
    ``translation`` the stitch aligned by it, and with ``halves`` each half of the stitch."""
    stitched = (TrialKind.STITCHED,) if settings.stitched else ()
    aligned = (TrialKind.ALIGNED,) if settings.translation else ()
    return (*stitched, *aligned, *(HALVES if settings.halves else ()))


def start_name(kind: str, translation: str | None = None) -> str:
    """A start's name in its trials' keys: ``few_shot`` for the stitch, ``aligned+<translation>``
    for the aligned stitch, else the kind (``robot_module``, ``task_module``)."""
    if kind == TrialKind.ALIGNED:
        return f"{kind}+{translation}"
    return "few_shot" if kind == TrialKind.STITCHED else kind


def start_file(spec: SweepSpec, pair: StitchedPair, kind: str, translation: str | None = None) -> Path:
    """Where the policy file of a start of the pair (``kind``: one of :func:`starts`; an aligned
    start names its ``translation``) stands: one name per (sources, start), so a resumed stage
    finds the files its trials started from."""
    name = f"{pair.task_from}|{pair.robot_from}"
    if kind != TrialKind.STITCHED:
        name += f"|{start_name(kind, translation)}"
    folder = sweep_layout(spec).stitched
    return folder / f"{hashlib.sha256(name.encode()).hexdigest()[:16]}.safetensors"


def plan(
    spec: SweepSpec, zoo: ModuleZoo, pairs: list[StitchedPair], settings: FewShotSpec | None = None
) -> list[TrainTrial]:
    """The stage's trials, from the evaluated pairs (:func:`ps_ray.plan.zero_shot.evaluated_pairs`,
    or the zero-shot plan's same-seed untranslated pairs): each selected pair's starts
    (:func:`starts`, from :func:`start_file`), the pair's robot source fine-tuned as it is
    (``unstitched``, once per target), and one from-scratch run per target (``scratch``). Starts
    from trained weights fit their critics alone for ``critic_warmup_updates`` updates first."""
    settings = settings or spec.few_shot
    trials, targets, seen = [], {}, set()
    for pair in selected_pairs(pairs, settings):
        base = TrainSpec.from_mapping(
            {
                **dict(spec.train),
                "method": pair.method,
                "robot": pair.robot,
                "task": pair.task,
                "seed": pair.seed,
                "interface_dim": zoo.get(pair.task_from).signature.interface_dim,  # the stitch's
                "env_steps": settings.env_steps,
                "learning_starts": settings.collect_steps,
                "random_episodes": 0,
            }
        )
        target = trial_key(base.to_dict())
        warm = {**base.to_dict(), "critic_warmup_updates": settings.critic_warmup_updates}
        for kind in starts(settings):
            path = start_file(spec, pair, kind, settings.translation)
            start = TrainSpec.from_mapping({**warm, "init_policy": str(path)})
            name = start_name(kind, settings.translation)
            trials.append(TrainTrial(start, key=f"{name}/{pair.label}/{target}", label=pair.label, kind=kind))
        own = pair.controls.get("robot_source")
        if settings.unstitched and own is not None:  # the robot source as it is, fine-tuned
            key = f"unstitched/{own.source}/{target}"
            if key not in seen:
                seen.add(key)
                unstitched = TrainSpec.from_mapping({**warm, "init_policy": own.path})
                trials.append(TrainTrial(unstitched, key=key, label=key, kind="unstitched"))
        targets.setdefault(target, base)
    if settings.scratch:  # PS from scratch uses the sweep's anchor set, as its stitched sources
        trials += [
            TrainTrial(base, anchor_file(spec, base), key=f"scratch/{key}", label=key, kind="scratch")
            for key, base in targets.items()
        ]
    return trials
