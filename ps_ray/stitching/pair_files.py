"""What a stitched pair's zero-shot evaluation leaves for its MLflow run: the stitched policy file
(loadable as any policy: ``ps-ray evaluate``, ``load_policy``) and its per-episode outcomes beside
each control's on the same episodes, so an analyst can pair them scene by scene."""

from __future__ import annotations

import hashlib
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import pandas as pd

STITCHED_FILE = "stitched.safetensors"
EPISODES_FILE = "episodes.csv"
PAIRS_FOLDER = "pairs"  # inside the stage's Tune folder, one folder per pair


def pair_folder(stage_dir: str | Path, pair_key: str) -> Path:
    """Where a pair's files stand: one folder per pair key, the same for every retry of its batch."""
    return Path(stage_dir) / PAIRS_FOLDER / hashlib.sha256(pair_key.encode()).hexdigest()[:16]


def episodes_table(stitched: Mapping[str, Any], controls: Mapping[str, Mapping[str, Any]]) -> pd.DataFrame:
    """One row per episode (``repeat``, reset ``seed``): the stitch's success, touching and
    wrong-target flags, then each control's success (``<role>_success``), all from
    :func:`ps_ray.stitching.evaluate.evaluate` results on the same episodes."""
    rows = [
        {
            "repeat": r["repeat"],
            "seed": r["seed"],
            "success": r["success"],
            "touched": r["touched"],
            "wrong_target": r["wrong_target"],
            "initially_successful": r["initially_successful"],
        }
        for r in stitched["records"]
    ]
    for role, result in controls.items():
        for row, record in zip(rows, result["records"], strict=True):
            if record["seed"] != row["seed"]:  # a bug, never bad input
                raise RuntimeError(f"the {role} control ran on other episodes")
            row[f"{role}_success"] = record["success"]
    return pd.DataFrame(rows)


def write_pair_files(
    folder: Path, nets, signature, metadata: Mapping[str, str], episodes: pd.DataFrame
) -> Path:
    """The stitched policy and its episodes in ``folder``, each written atomically."""
    from ps_ray.nets.policy_file import save_policy
    from ps_ray.store.atomic import atomic_path

    save_policy(folder / STITCHED_FILE, nets, signature, extra=dict(metadata))
    with atomic_path(folder / EPISODES_FILE) as partial:
        episodes.to_csv(partial, index=False)
    return folder
