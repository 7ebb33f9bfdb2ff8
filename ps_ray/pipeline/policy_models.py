"""A trained policy as a logged MLflow model (pyfunc, from code: :mod:`ps_ray.pipeline.policy_model_code`),
so ``mlflow.pyfunc.load_model("runs:/<run>/<its name>")`` and the model registry can use it, with an
input example (a real observation of the policy's own env) and the signature inferred from it."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import numpy as np

MODEL_TAG = "ps_ray.model"  # on the run: its model's name (runs:/<run id>/<name>)


def model_name(title: str) -> str:
    """A run's title as a model name MLflow takes (``panda_far-reach_blue-ablation-431``), so the
    experiment's Models list tells its policies apart."""
    return re.sub(r"[^A-Za-z0-9_]+", "-", title).strip("-")[:120]  # MLflow refuses a dot, slash, colon


CODE_FILE = Path(__file__).with_name("policy_model_code.py")  # run by MLflow, not imported here


def example_observation(robot: Any, task: Any) -> dict[str, np.ndarray]:
    """The first observation of ``make(robot, task)``, as a batch of one."""
    from ps_ray.envs.core import make

    env = make(robot, task)
    try:
        obs, _ = env.reset(seed=0)
    finally:
        env.close()
    return {key: np.asarray(value, np.float32)[None] for key, value in obs.items()}


def log_policy_model(
    tracking_uri: str, run_id: str, policy_file: str | Path, robot: Any, task: Any, title: str
) -> str:
    """Log ``policy_file``, trained on (``robot``, ``task``), as a model of run ``run_id`` named
    after the run's ``title``; returns the model's name (also the run's :data:`MODEL_TAG`)."""
    import mlflow
    from mlflow.models import infer_signature

    from ps_ray.nets.policy import GreedyPolicy

    example = example_observation(robot, task)
    actions = GreedyPolicy.from_file(policy_file)(example)
    previous = mlflow.get_tracking_uri()
    mlflow.set_tracking_uri(tracking_uri)
    try:
        name = model_name(title)
        with mlflow.start_run(run_id=run_id):
            mlflow.pyfunc.log_model(
                name=name,
                python_model=str(CODE_FILE),
                artifacts={"policy": str(policy_file)},  # policy_model_code.POLICY_ARTIFACT
                input_example=example,
                signature=infer_signature(example, actions),
                pip_requirements=["ps_ray", "torch", "numpy"],  # no inference: it loads the model again
            )
            mlflow.set_tag(MODEL_TAG, name)  # once the model exists
    finally:
        mlflow.set_tracking_uri(previous)
    return name
