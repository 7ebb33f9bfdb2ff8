"""What a stage launched, read back from its folders, beside what its plan lists from the spec
alone (:mod:`ps_ray.plan` on the catalogue the spec implies): the check that what ``--check``
prices is what runs."""

from __future__ import annotations

import json
from pathlib import Path

from ps_ray.plan import few_shot, grid, train, zero_shot
from ps_ray.plan.catalogue import planned
from ps_ray.specs.sweep import SweepSpec
from ps_ray.specs.trial import STITCHED_STARTS, TrainTrial
from ps_ray.store.attempts import attempts, identity, rows_naming
from ps_ray.store.layout import sweep_layout


def _launched(folder: Path) -> set[str]:
    return set(attempts(folder, "trial"))


def _start_free(config: dict) -> str:
    """A training trial without the file it starts from, unless that file is a stitched start
    (its name is planned): a robot source's file is named by Tune when it trains."""
    trial = TrainTrial.of(config)
    spec = trial.spec.to_dict()
    if trial.kind not in STITCHED_STARTS:
        spec["init_policy"] = spec["init_policy"] and "<a source's file>"
    return identity([trial.run_name, trial.kind, trial.anchors, spec])


def assert_stages_launched_their_plans(
    spec: SweepSpec, zero_shot_settings=None, few_shot_settings=None
) -> None:
    layout = sweep_layout(spec)
    zoo = planned(spec)
    if "train" in spec.stages:
        assert _launched(layout.tune_train) == {identity(t.config()) for t in train.plan(spec)}
        assert _launched(layout.tune_plain) == {identity(t.config()) for t in train.plain_sources(spec)}
    if "grid" in spec.stages:
        assert _launched(layout.tune_grid) == {identity(t.config()) for t in grid.plan(spec)}
    if "zero_shot" in spec.stages:
        ran = rows_naming(layout.tune_zero_shot, "pair_key")
        pairs = zero_shot.plan(spec, zoo, zero_shot_settings)
        assert sorted(ran) == sorted(p.key for p in pairs)
        table = {row["key"]: row for row in _csv(layout.zero_shot_table)}
        for pair in pairs:  # the same controls, by their sources
            assert {r: c.source for r, c in pair.controls.items()} == {
                r: table[pair.key][r] for r in ("robot_source", "task_source", "oracle") if table[pair.key][r]
            }
    if "few_shot" in spec.stages:
        settings = few_shot_settings or spec.few_shot
        pairs = zero_shot.alone_pairs(spec, zoo, list(settings.methods) or None)
        trials = few_shot.plan(spec, zoo, pairs, settings)
        assert {_start_free(json.loads(k)) for k in _launched(layout.tune_few_shot)} == {
            _start_free(t.config()) for t in trials
        }


def _csv(path: Path) -> list[dict]:
    import csv

    with path.open(newline="") as f:
        return list(csv.DictReader(f))
