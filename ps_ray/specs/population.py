"""PopulationSpec: several sources of a sweep trained in one learner (docs/cost.md "Populations").

Its members are ordinary training specs that differ only in robot, task and seed (for a gymnasium
env given by id: only in seed): one method, widths and settings, so their networks stack
(:mod:`ps_ray.nets.population`). Each member is still its own source: its own env, reset-seed
block, replay, normalisers, stopping rule, policy file and spec, so every later stage reads it as
it reads a source trained alone.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from ps_ray.envs.core import env_widths
from ps_ray.specs.defaults import INTERFACE_DIM
from ps_ray.specs.train import SpecError, TrainSpec

MEMBER_FIELDS = ("robot", "task", "seed")  # what may differ between a population's members


def shared_settings(spec: TrainSpec) -> dict[str, Any]:
    """What a population's members must share: every setting of the spec but robot, task, seed."""
    return {k: v for k, v in spec.to_dict().items() if k not in MEMBER_FIELDS}


@dataclass(frozen=True)
class PopulationSpec:
    members: tuple[TrainSpec, ...]

    def __post_init__(self) -> None:
        members = tuple(self.members)
        object.__setattr__(self, "members", members)
        if not members:
            raise SpecError("a population needs at least one member")
        labels = [m.label() for m in members]
        if len(set(labels)) != len(labels):
            raise SpecError(f"a population's members repeat one: {labels}")
        first = shared_settings(members[0])
        for member in members[1:]:
            other = shared_settings(member)
            differ = sorted(k for k in {*first, *other} if first.get(k) != other.get(k))
            if differ:
                raise SpecError(
                    f"a population's members may differ only in {', '.join(MEMBER_FIELDS)}; "
                    f"{member.label()} differs from {members[0].label()} in {', '.join(differ)}"
                )
        if first.get("init_policy") is not None:
            raise SpecError("a population trains its sources from fresh modules (no init_policy)")
        if members[0].resolved.consolidate is not None:
            raise SpecError(
                f"{members[0].method} consolidates its actor when a run ends; a population trains "
                "methods without that step (train its sources alone)"
            )
        if members[0].env is not None:
            return  # one gymnasium env, as every member's shared settings say: one set of widths
        widths = {m.label(): env_widths(m.robot, m.task) for m in members}
        if len(set(widths.values())) > 1:
            raise SpecError(
                "a population's members must share their widths (task input, robot state, action); got "
                + ", ".join(f"{k} {v}" for k, v in widths.items())
            )

    @property
    def base(self) -> TrainSpec:
        """The settings every member shares (budget, stopping rule, sizes), as the first member."""
        return self.members[0]

    def to_dict(self) -> dict[str, Any]:
        return {"members": [m.to_dict() for m in self.members]}

    @classmethod
    def from_mapping(cls, data: Mapping[str, Any], where: str = "population spec") -> PopulationSpec:
        if not isinstance(data, Mapping) or set(data) != {"members"}:
            raise SpecError(f"{where}: expected one key, members")
        return cls(
            tuple(
                TrainSpec.from_mapping(m, where=f"{where}.members[{i}]")
                for i, m in enumerate(data["members"])
            )
        )

    def identity(self) -> dict[str, Any]:
        """What defines the population being trained; budgets and reporting may change on resume."""
        return {"members": [m.identity() for m in self.members]}

    @property
    def run_key(self) -> str:
        """Its MLflow run name: ``population/<method>[/i<dim>]/<K>x<digest of its members>``."""
        spec = self.base
        width = "" if spec.interface_dim == INTERFACE_DIM else f"/i{spec.interface_dim}"
        digest = hashlib.sha256(json.dumps(self.identity(), sort_keys=True).encode()).hexdigest()
        return f"population/{spec.method}{width}/{len(self.members)}x{digest[:10]}"

    def label(self) -> str:
        return f"population of {len(self.members)} {self.base.method} sources"
