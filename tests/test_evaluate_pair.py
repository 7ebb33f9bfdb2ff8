"""One stitched pair scored as a zero-shot trial scores it (:func:`ps_ray.pipeline.zero_shot.evaluate_pair`),
in process, on the shipped example zoo's real modules: as they are and translated by a fit on
their rolled-out outcomes, beside the same controls, chance and floor on the same episodes."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest

from ps_ray.nets.policy_file import load_policy
from ps_ray.pipeline.zero_shot import Sources, evaluate_pair
from ps_ray.plan.zero_shot import Episodes, FitSettings
from ps_ray.stitching.chance import chance
from ps_ray.stitching.example import ExampleZoo
from ps_ray.stitching.outcomes import fit_env_steps
from ps_ray.stitching.pair_files import EPISODES_FILE, STITCHED_FILE
from ps_ray.stitching.pairs import Control, StitchedPair
from ps_ray.store.signature import read_signature

pytestmark = pytest.mark.e2e  # rolls out a few hundred physics episodes


def zoo_pair(zoo: ExampleZoo, translation: str) -> StitchedPair:
    modules = zoo.manifest["modules"]
    (robot, task), t, r = zoo.target, modules["task_module"], modules["robot_module"]
    role = {"robot_source": "robot_module", "task_source": "task_module", "oracle": "oracle"}
    return StitchedPair(
        key=f"zero_shot/ablation+{translation}" if translation else "zero_shot/ablation",
        method=f"ablation+{translation}" if translation else "ablation",
        translation=translation,
        pairing="same_seed",
        seed=406,
        robot_seed=406,
        label="t: reach_blue & r: panda_far",
        task_from="task module",
        robot_from="robot module",
        task_from_path=str(zoo.path("task_module")),
        robot_from_path=str(zoo.path("robot_module")),
        robot=robot,
        task=task,
        task_from_robot=t["trained_on"]["robot"],
        robot_from_robot=r["trained_on"]["robot"],
        robot_from_task=r["trained_on"]["task"],
        controls={k: Control(k, str(zoo.path(v))) for k, v in role.items()},
    )


def test_a_pair_and_its_outcome_translation_are_scored_beside_the_same_controls(tmp_path):
    zoo = ExampleZoo.load()
    episodes = Episodes(10, 1, zoo.episodes["seed"])  # the first 10 of the study's episodes
    fit = FitSettings(
        states_per_quadrant=8, scenes=40, points=256, cache=str(tmp_path / "outcomes"), seed=0, fit_seed=1
    )
    robot, task = zoo.target
    levels = chance(robot, task, episodes.kwargs())
    sources = Sources()
    plain = evaluate_pair(zoo_pair(zoo, ""), episodes, fit, levels, sources, tmp_path / "plain")
    fitted = evaluate_pair(
        zoo_pair(zoo, "affine@outcome"), episodes, fit, levels, sources, tmp_path / "fitted"
    )
    for metrics in (plain, fitted):
        assert metrics["episodes_seed"] == episodes.seed
        # the sources as they are, on the target: the robot module's source reaches the other
        # marker and the task module's source drives the other arm, so neither succeeds here
        assert metrics["robot_source_success"] == metrics["task_source_success"] == 0.0
        assert metrics["oracle_success"] >= 0.8
        controls = [metrics[f"{k}_success"] for k in ("robot_source", "task_source", "chance", "task_blind")]
        assert metrics["best_control"] == max(controls) and metrics["task_blind_success"] == 0.5
        assert metrics["transfer_gain"] == pytest.approx(metrics["success_mean"] - max(controls))
        # told the task (the markers traded in what it reads), the robot source reaches the named
        # marker: the ceiling of any map between the two task modules; no control the gain counts
        assert metrics["told_robot_source_success"] >= 0.8
    # both stitches stand beside the same controls' figures, on the same episodes
    assert {k: plain[k] for k in plain if "source" in k or "oracle" in k} == {
        k: fitted[k] for k in fitted if "source" in k or "oracle" in k
    }
    assert plain["fit_env_steps"] == 0 and math.isnan(plain["translation_ridge"])
    assert fitted["fit_env_steps"] == fit_env_steps("affine", "outcome", 40)
    assert 0 < fitted["translation_ridge"] < np.inf  # the ridge strength its cross-validation chose
    assert plain["success_mean"] >= 0.5  # the co-trained cells share their latent: stitched as they are
    # each stitch leaves its policy and its episodes beside the controls' on the same scenes
    for folder, metrics in ((tmp_path / "plain", plain), (tmp_path / "fitted", fitted)):
        table = pd.read_csv(folder / EPISODES_FILE)
        assert len(table) == 10 and table["success"].mean() == pytest.approx(metrics["success_mean"])
        assert (
            table["robot_source_success"].sum() == 0
            and table["oracle_success"].mean() == metrics["oracle_success"]
            and table["told_robot_source_success"].mean() == metrics["told_robot_source_success"]
        )
        assert load_policy(folder / STITCHED_FILE)[1] is not None
    assert float(
        read_signature(tmp_path / "fitted" / STITCHED_FILE)[1]["translation_ridge"]
    ) == pytest.approx(fitted["translation_ridge"], rel=1e-5)


def test_a_resumed_stage_reads_its_chance_levels_instead_of_measuring_them_again(tmp_path, monkeypatch):
    """The zero-shot stage keeps each target env's chance level and floor in the sweep folder: a
    resumed stage reads the same figures back and runs no chance episode; other episodes (another
    count) are measured afresh."""
    import ps_ray.stitching.chance
    from ps_ray.pipeline.chance_levels import chance_levels

    pair, stream = zoo_pair(ExampleZoo.load(), ""), Episodes(2, 1, 0)
    first = chance_levels([pair], stream, progress=False, kept=tmp_path)
    (level,) = first.values()
    assert 0 <= level["chance_success"] <= 1 and level["task_blind_success"] == 0.5  # two markers
    assert len(list(tmp_path.glob("*.json"))) == 1

    def measured(*args, **kwargs):
        raise AssertionError("a kept chance level was measured again")

    monkeypatch.setattr(ps_ray.stitching.chance, "chance", measured)
    assert chance_levels([pair], stream, progress=False, kept=tmp_path) == first
    with pytest.raises(AssertionError, match="measured again"):
        chance_levels([pair], Episodes(3, 1, 0), progress=False, kept=tmp_path)
