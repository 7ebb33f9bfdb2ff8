"""The zero-shot stage's chance levels and task-blind floors: measured once per target env and
episodes, and kept in the sweep folder so that a resumed stage reads them back."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

from ps_ray.plan.zero_shot import Episodes, pair_episodes, target_key
from ps_ray.specs.names import readable
from ps_ray.stitching.pairs import StitchedPair
from ps_ray.stitching.zoo import ModuleZoo
from ps_ray.store.atomic import write_text
from ps_ray.store.formats import CHANCE


def chance_levels(
    trials: list[StitchedPair],
    stream: Episodes,
    progress: bool,
    zoo: ModuleZoo | None = None,
    kept: Path | None = None,
) -> dict[str, dict]:
    """The chance control and task-blind floor (:func:`ps_ray.stitching.chance.chance`) of every
    target env the pairs run on, on each seed's episodes (:func:`pair_episodes` of ``stream``):
    they depend on nothing else, so each is measured once. Where no script does the scene's tasks
    (the push family), the floor runs the ``zoo``'s oracles of the scene's tasks at the pair's seed
    (:func:`ps_ray.stitching.chance.scene_oracles`). With ``kept`` (a folder), each level that
    needs no oracles is written there once and read back by a resumed stage, not measured again."""
    from ps_ray.stitching.chance import chance, has_floor, scene_oracles, scripted_floor

    levels = {}
    for pair in trials:
        episodes = pair_episodes(pair, stream)
        key = target_key(pair, episodes)
        if key not in levels:
            oracles = None
            if zoo is not None and has_floor(pair.task) and not scripted_floor(pair.task):
                oracles = scene_oracles(zoo, pair.robot, pair.task, pair.seed)
            file = (
                None if kept is None or oracles is not None else kept / f"{_chance_name(pair, episodes)}.json"
            )
            if (found := _kept_level(file)) is not None:
                levels[key] = found
                continue
            levels[key] = chance(pair.robot, pair.task, episodes.kwargs(), oracles)
            if file is not None:
                file.parent.mkdir(parents=True, exist_ok=True)
                write_text(file, json.dumps({"format": CHANCE.id, "levels": levels[key]}))
            if progress:
                found = levels[key]
                floor = found["task_blind_success"]
                floor_text = "absent" if floor != floor else f"{floor:.3f} ({found['task_blind_policy']})"
                print(
                    f"[zero_shot] chance on {readable(pair.task.short)}/{pair.robot.short}, seed "
                    f"{pair.seed}'s episodes: {found['chance_success']:.3f} ({found['chance_policy']}); "
                    f"task-blind floor {floor_text}",
                    flush=True,
                )
    return levels


def _kept_level(file: Path | None) -> dict | None:
    """A chance level kept by an earlier run of the stage (None: none, unreadable, or of another
    format: it is measured again)."""
    if file is None or not file.exists():
        return None
    try:
        kept = json.loads(file.read_text())
    except (OSError, ValueError):  # damaged by hand or by the disk: measuring again costs minutes
        return None
    return kept.get("levels") if isinstance(kept, dict) and kept.get("format") == CHANCE.id else None


def _chance_name(pair: StitchedPair, episodes: Episodes) -> str:
    """A kept chance file's name: a digest of the target env and its episodes."""
    what = {"robot": pair.robot.text, "task": pair.task.text, "episodes": episodes.kwargs()}
    return hashlib.sha256(json.dumps(what, sort_keys=True).encode()).hexdigest()[:20]
