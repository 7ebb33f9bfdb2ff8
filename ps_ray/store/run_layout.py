"""The file names of a run folder (`ps-ray train --run-dir`, and each training trial) and of the
policy inside a checkpoint, in one place (docs/state.md). A sweep folder's paths are in
:class:`ps_ray.store.layout.SweepLayout`; a checkpoint's own files in :mod:`ps_ray.store.checkpoint`."""

SPEC_FILE = "spec.json"  # the run's TrainSpec; also written into every checkpoint
ANCHORS_FILE = "anchors.npz"  # PS: the run's anchor set
CHECKPOINT_DIR = "checkpoint"  # the sealed checkpoint, swapped in through .tmp and .old
REPLAY_FOLDER = "replay"  # the replay buffer's segment files (ps_ray.store.replay), for every checkpoint
POLICY_FILE = "policy.safetensors"  # the latest policy (also inside every checkpoint)
SIGNATURE_FILE = "signature.json"  # the policy's interface signature, inside every checkpoint
BEST_POLICY_FILE = "best_policy.safetensors"  # the best greedy evaluation so far
METRICS_FILE = "metrics.csv"  # one row per training step
RESULT_FILE = "result.json"  # the final figures of a finished run (a grid: and of each cell)

# A co-trained grid's folder (`ps-ray grid --run-dir`) and checkpoint (ps_ray.rllib.grid_train)
GRID_FILE = "grid.json"  # the GridSpec; also in every checkpoint
CELLS_FOLDER = "cells"  # each trained cell as a source: cells/<robot>-<task>/{spec.json, policy.safetensors}


# A population's checkpoint (ps_ray.rllib.population_train): its members as a grid's cells, and
POPULATION_FILE = "population.json"  # the PopulationSpec; in every checkpoint


def cell_policy_file(index: int) -> str:
    """The ``index``-th trained cell's policy file in a grid checkpoint."""
    return f"policy_c{index:02d}.safetensors"  # c00, c01, ...: the grid env's cell keys


def cell_spec_file(index: int) -> str:
    """Its TrainSpec, beside it."""
    return f"spec_c{index:02d}.json"


def cell_result_file(index: int) -> str:
    """A population member's final figures, once it has stopped."""
    return f"result_c{index:02d}.json"


# The columns of metrics.csv, one row per training step (also the keys of a sweep trial's results)
METRIC_FIELDS = (
    "iteration",
    "env_steps",
    "updates",
    "train_success",
    "train_touching",
    "eval_success",
    "eval_touching",
    "best_eval_success",  # the best greedy success so far, kept across resumes
    "wall_s",
)
