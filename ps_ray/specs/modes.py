"""The settings that name one of a few modes, as enums. A spec reads what a YAML file or a flag
wrote (a string) into the member; anything else is one line naming the setting and listing the
choices. Members are strings (``StrEnum``): they compare equal to, and are written as, the words
the sweep files use."""

from __future__ import annotations

from enum import StrEnum
from typing import Any, Self

from ps_ray.errors import UserError


class Mode(StrEnum):
    @classmethod
    def of(cls, value: Any, where: str, listing: str = "valid") -> Self:
        """The member ``value`` names; one line naming ``where`` and the choices otherwise."""
        if isinstance(value, str) and value in cls._value2member_map_:
            return cls(value)
        raise UserError(f"unknown {where} {value!r}; {listing}: {', '.join(cls)}")


class AnchorPolicy(Mode):
    """Where anchor states come from: greedy rollouts of trained plain policies (the paper), or
    random actions."""

    PLAIN = "plain"
    RANDOM = "random"


class AnchorGoals(Mode):
    """The desired goals of anchor states: their own, or hindsight-relabelled (ps_ray.data.collect)."""

    REAL = "real"
    RELABELLED = "relabelled"


class Pairing(Mode):
    """Which modules meet in the zero-shot matrix: of one training seed, of two seeds (seed i's
    task modules with seed i+1's robot modules, separate training runs), or both."""

    SAME_SEED = "same_seed"
    CROSS_SEED = "cross_seed"
    BOTH = "both"


def same_seed_first(pairing: str) -> bool:
    """A sort key that lists same-seed rows and panels (the headline pairing) before cross-seed ones."""
    return pairing != Pairing.SAME_SEED


class Scheduler(Mode):
    """A search's trial scheduler: Tune's ASHA, or none (every trial runs out)."""

    ASHA = "asha"
    NONE = "none"


class SearchMetric(Mode):
    """What ASHA compares at a rung: the greedy success of that evaluation, or the best so far."""

    EVAL_SUCCESS = "eval_success"
    BEST_EVAL_SUCCESS = "best_eval_success"


class TrialKind(Mode):
    """What a training trial is: a source (or an anchor policy), or a few-shot start: the stitched
    pair (as it is, or aligned), one half of it beside a fresh other half, the pair's robot source as
    it is, or scratch."""

    TRAIN = "train"
    STITCHED = "stitched"
    ALIGNED = "aligned"  # the stitch aligned by a fitted latent map, folded in (ps_ray.stitching.fold)
    ROBOT_MODULE = "robot_module"
    TASK_MODULE = "task_module"
    UNSTITCHED = "unstitched"
    SCRATCH = "scratch"
