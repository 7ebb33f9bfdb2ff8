"""MLflow's "model from code" of a ps_ray policy: the file MLflow runs (never unpickles) when a
logged policy is loaded with ``mlflow.pyfunc.load_model(uri)``; ``predict(obs)`` maps a batch of
Dict observations (``task_state``, ``desired_goal``, ``robot_state``: each a 2-D array, one row
per observation) to the greedy actions. Logged by :func:`ps_ray.pipeline.policy_models.log_policy_model`;
not imported by ps_ray itself (it registers the model with MLflow when it runs)."""

from __future__ import annotations

import mlflow
import numpy as np
from mlflow.pyfunc import PythonModel

POLICY_ARTIFACT = "policy"  # the policy file, among the model's artifacts


class PolicyModel(PythonModel):
    def load_context(self, context) -> None:
        from ps_ray.nets.policy import GreedyPolicy

        self.policy = GreedyPolicy.from_file(context.artifacts[POLICY_ARTIFACT])

    def predict(self, context, model_input, params=None) -> np.ndarray:
        return self.policy({key: np.asarray(value, np.float32) for key, value in model_input.items()})


mlflow.models.set_model(PolicyModel())
