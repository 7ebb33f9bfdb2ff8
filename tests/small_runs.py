"""Training settings and hostile files the tests share: runs small enough for a test, and pickles
that mark it if anything ever loads them."""

from __future__ import annotations

from tests.point_env import POINT_ENV

# A small `ps-ray train` on the point task: PS, interface 8, checkpoints every 3 steps.
TRAIN_ARGS = (
    f"--env {POINT_ENV} --method ps --interface-dim 8 --hidden 32 --learning-starts 200 "
    "--random-episodes 2 --episodes-per-step 4 --checkpoint-every 3 --eval-every 3 "
    "--eval-episodes 4 --batch-size 64 --anchor-episodes 20"
).split()


# Training settings small enough for a sweep of several trials in a test (real RLlib runs).
TINY_TRAIN = {
    "env_steps": 300,
    "hidden": 32,
    "learning_starts": 100,
    "random_episodes": 2,
    "eval_every": 2,
    "eval_episodes": 2,
    "checkpoint_every": 2,
    "batch_size": 32,
}


# A co-trained grid's or a population's cells at test size (real RLlib runs, one env each).
CELL_TRAIN = {
    "method": "ablation",
    "hidden": 32,
    "interface_dim": 8,
    "learning_starts": 100,
    "random_episodes": 1,
    "episodes_per_step": 1,
    "num_envs": 1,
    "eval_every": 2,
    "eval_episodes": 2,
    "checkpoint_every": 2,
    "batch_size": 32,
}


class HostilePickle:
    """A pickle that, if ever loaded, writes a marker file."""

    def __init__(self, marker):
        self.marker = str(marker)

    def __reduce__(self):
        return (exec, (f"open({self.marker!r}, 'w').write('pickle ran')",))


RAY_PICKLES = ("algorithm_state.pkl", "class_and_ctor_args.pkl", "state.pkl", "params.pkl", "tuner.pkl")
