"""The three widths every network and policy file is built from (torch-free: a policy file's
signature, :mod:`ps_ray.store.signature`, gives them without loading the nets)."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class NetDims:
    task_dim: int  # task state (+ desired goal)
    robot_dim: int  # joint angles + finger width
    action_dim: int
