"""One record per stitched pair: the zero-shot trials' configs and the rows of zero_shot.csv
(no Ray, no training)."""

from __future__ import annotations

import json

import pandas as pd
import pytest

from ps_ray.pipeline.zero_shot import table_of, write_atomic_csv
from ps_ray.stitching.pairs import Control, StitchedPair

Q1, Q3 = {"name": "reach", "goal_region": "q1"}, {"name": "reach", "goal_region": "q3"}
GRIPPER = {"name": "panda_l3", "gripper": True}


def a_pair(translation: str = "") -> StitchedPair:
    method = f"ps+{translation}" if translation else "ps"
    return StitchedPair(
        key=f"zero_shot/{method}/t: q1 & r: q3/1",
        method=method,
        translation=translation,
        pairing="same_seed",
        seed=1,
        robot_seed=1,
        label="t: q1 & r: q3",
        task_from="ps/panda/reach/1/i8",
        robot_from="ps/panda_l3/reach/1/i8",
        task_from_path="/sweep/tune/a/policy.safetensors",
        robot_from_path="/sweep/tune/b/policy.safetensors",
        robot=GRIPPER,
        task=Q1,
        task_from_robot="panda",
        robot_from_robot=GRIPPER,
        robot_from_task=Q3,
        controls={
            "robot_source": Control("ps/panda_l3/reach/1/i8", "/sweep/tune/b/policy.safetensors"),
            "task_source": Control("ps/panda/reach/1/i8", "/sweep/tune/a/policy.safetensors"),
        },
    )


@pytest.mark.parametrize("translation", ["", "orthogonal"])
def test_a_pair_survives_the_tune_config_and_the_csv_row(tmp_path, translation):
    pair = a_pair(translation)
    assert StitchedPair.from_dict(json.loads(json.dumps(pair.to_dict()))) == pair
    assert StitchedPair.from_row(pair.to_row()) == pair
    row = pair.to_row()
    assert row["task"] == '{"goal_region": "q1", "name": "reach"}'  # exact, not the short name
    assert (row["robot_source"], row["robot_source_path"]) == (pair.robot_from, pair.robot_from_path)
    assert (row["oracle"], row["oracle_path"]) == ("", "")  # no oracle trained for this target
    assert pair.fit_tasks == (Q1, Q3)
    # MLflow params as before the record: no paths, envs by short name
    assert pair.shown()["task"] == 'reach{"goal_region":"q1"}'
    assert not any("path" in k for k in pair.shown())
    # as zero_shot.csv: written by the zero-shot stage, read back cell by cell as text
    path = tmp_path / "zero_shot.csv"
    write_atomic_csv(table_of([(pair, {"success_mean": 0.5})]), path)
    (row,) = pd.read_csv(path, dtype=str, keep_default_na=False).to_dict("records")
    assert StitchedPair.from_row(row) == pair and row["task_from_path"] == pair.task_from_path
