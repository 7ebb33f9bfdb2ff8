"""Plain-torch networks for Policy Stitching (no Ray imports here)."""

from ps_ray.nets.mlp import mlp
from ps_ray.nets.modular import (
    Actor,
    ActorRobotModule,
    Critic,
    CriticRobotModule,
    NetDims,
    TaskModule,
    build_actor,
    build_critic,
    count_parameters,
    update_normalizers,
)
from ps_ray.nets.normalize import RunningNorm
from ps_ray.nets.relative import RelativeProjection
from ps_ray.specs.methods import MethodSpec, RelativeSpec, method_spec

__all__ = [
    "Actor",
    "ActorRobotModule",
    "Critic",
    "CriticRobotModule",
    "MethodSpec",
    "NetDims",
    "RelativeProjection",
    "RelativeSpec",
    "RunningNorm",
    "TaskModule",
    "build_actor",
    "build_critic",
    "count_parameters",
    "method_spec",
    "mlp",
    "update_normalizers",
]
