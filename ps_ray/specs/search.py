"""A sweep's hyperparameter search (its ``search:`` block): training settings drawn by Ray Tune's
random search, each applied to every trial of the grid, and trials cut short by Tune's ASHA
scheduler on the greedy success curve (docs/search.md).

The draws are Tune's own (``generate_variants``, the resolver of its ``BasicVariantGenerator``)
from the block's seed, so the same spec always yields the same trials: a killed search resumes
from them like any sweep, and ``--check`` lists and prices them. Drawing imports Ray (not torch):
only a sweep with a search pays for it.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from typing import Annotated, Any

from pydantic import Field

from ps_ray.specs.engine import OneOf, Positive, SpecError, spec
from ps_ray.specs.modes import Scheduler, SearchMetric
from ps_ray.specs.names import readable
from ps_ray.specs.train import TrainSpec

# How a setting is drawn: the Tune sample function each one maps to (ray.tune.search.sample).
DISTRIBUTIONS = ("choice", "uniform", "loguniform", "randint")
SCHEDULERS = tuple(Scheduler)
METRICS = tuple(SearchMetric)  # columns of a trial's result rows
# Settings a search may not draw: the grid's own keys and the budget every trial shares.
NOT_SEARCHED = ("method", "robot", "task", "seed", "interface_dim", "env_steps", "target_success", "anchors")
SEARCHABLE = tuple(f.name for f in dataclasses.fields(TrainSpec) if f.name not in NOT_SEARCHED)


@spec("search")
class SearchSpec:
    """``space`` maps a ``train`` key to one distribution, e.g. ``{loguniform: [1e-4, 3e-3]}``,
    ``{choice: [0.95, 0.98]}``; an empty space is no search."""

    space: Mapping[str, Any] = dataclasses.field(default_factory=dict)
    samples: Positive = 8  # settings drawn; every trial of the grid runs once per setting
    seed: int = 0  # random state of the draws
    # Tune's ASHA on ``metric`` over env steps, or none
    scheduler: OneOf[Scheduler] = Scheduler.ASHA
    metric: OneOf[SearchMetric] = SearchMetric.EVAL_SUCCESS  # what ASHA compares at a rung
    grace_env_steps: Positive = 25_000  # no trial is stopped before this many env steps (ASHA's first rung)
    reduction_factor: Annotated[int, Field(ge=2)] = 3  # ASHA keeps the top 1/reduction_factor of each rung

    def __post_init__(self) -> None:
        for key, value in self.space.items():
            _check_distribution(key, value)

    @property
    def active(self) -> bool:
        return bool(self.space)

    def tune_space(self) -> dict[str, Any]:
        """The space as Tune sample domains (imports Ray)."""
        from ray import tune

        out = {}
        for key, value in self.space.items():
            ((kind, args),) = value.items()
            out[key] = tune.choice(list(args)) if kind == "choice" else getattr(tune, kind)(*args)
        return out

    def draws(self) -> list[dict[str, Any]]:
        """The ``samples`` settings, drawn by Tune's random search from ``seed`` (the same list
        every time); a choice of one value is that value."""
        import numpy as np
        from ray.tune.search.variant_generator import generate_variants

        random_state = np.random.RandomState(self.seed)
        out = []
        for _ in range(self.samples):
            ((_, config),) = generate_variants(self.tune_space(), random_state=random_state)
            out.append({k: _plain(v) for k, v in config.items()})
        return out

    def rungs(self, max_env_steps: int) -> list[int]:
        """ASHA's rungs (env steps at which a trial below the cut is stopped), as Tune builds them."""
        if self.scheduler == Scheduler.NONE or self.grace_env_steps >= max_env_steps:
            return []
        count = int(math.log(max_env_steps / self.grace_env_steps) / math.log(self.reduction_factor) + 1)
        rungs = (self.grace_env_steps * self.reduction_factor**k for k in range(count))
        return [r for r in rungs if r < max_env_steps]  # one at the budget ends a trial that ends anyway

    def nominal_env_steps(self, trials: int, max_env_steps: int) -> float:
        """Env steps of ``trials`` trials if ASHA keeps 1/reduction_factor at each rung (a trial
        stopped at a rung ran to it); with no scheduler, every trial runs out."""
        total, alive, start = 0.0, float(trials), 0
        for rung in self.rungs(max_env_steps):
            total += alive * (rung - start)
            alive, start = alive / self.reduction_factor, rung
        return total + alive * (max_env_steps - start)


def describe(search: SearchSpec, named_trials: list[tuple[str, TrainSpec]]) -> list[str]:
    """``--check``'s lines: every trial (with its drawn setting), then what the search costs."""
    lines = []
    for setting, trial in named_trials:
        drawn = ""
        if setting:
            values = ", ".join(f"{k}={_short(getattr(trial, k))}" for k in search.space)
            drawn = f"  {setting}: {values}"
        lines.append(f"  {readable(trial.label())}  {trial.env_steps} env steps{drawn}")
    if not search.active:
        return lines
    cap = max(t.env_steps for _, t in named_trials)
    per_setting = len(named_trials) // search.samples
    lines.append(
        f"search: {search.samples} settings drawn by Tune's random search (seed {search.seed}), "
        f"each on {per_setting} trial(s) of the sweep"
    )
    rungs = search.rungs(cap)
    if rungs:
        nominal = search.nominal_env_steps(len(named_trials), cap)
        lines.append(
            f"  ASHA on {search.metric} stops a trial in the bottom {search.reduction_factor - 1}/"
            f"{search.reduction_factor} at {', '.join(f'{r:,}' for r in rungs)} env steps: nominally "
            f"{nominal:,.0f} env steps, {nominal / (cap * len(named_trials)):.0%} of the full budgets "
            f"the cost below assumes"
        )
    return lines


def _short(value: Any) -> str:
    return f"{value:.3g}" if isinstance(value, float) else str(value)


def name(index: int) -> str:
    """The name of a drawn setting in run names, tables and plots."""
    return f"search{index:02d}"


def _plain(value: Any) -> Any:
    """A numpy scalar Tune drew, as the Python number a spec holds."""
    return value.item() if hasattr(value, "item") else value


def _check_distribution(key: str, value: Any) -> None:
    if key not in SEARCHABLE:
        raise SpecError(f"search.space: {key!r} cannot be searched; valid: {', '.join(SEARCHABLE)}")
    if not isinstance(value, Mapping) or len(value) != 1:
        raise SpecError(
            f"search.space.{key} must be one distribution, e.g. {{loguniform: [0.0001, 0.003]}}, "
            f"got {value!r}; valid: {', '.join(DISTRIBUTIONS)}"
        )
    ((kind, args),) = value.items()
    if kind not in DISTRIBUTIONS:
        valid = ", ".join(DISTRIBUTIONS)
        raise SpecError(f"search.space.{key}: unknown distribution {kind!r}; valid: {valid}")
    if not isinstance(args, (list, tuple)) or not args:
        raise SpecError(f"search.space.{key}.{kind} must be a non-empty list, got {args!r}")
    if kind == "choice":
        return
    numbers = all(isinstance(a, (int, float)) and not isinstance(a, bool) for a in args)
    if len(args) != 2 or not numbers or not args[0] < args[1]:
        raise SpecError(f"search.space.{key}.{kind} must be [low, high] with low < high, got {list(args)}")
    if kind == "loguniform" and args[0] <= 0:
        raise SpecError(f"search.space.{key}.loguniform needs a positive low, got {args[0]}")
    if kind == "randint" and not all(isinstance(a, int) for a in args):
        raise SpecError(f"search.space.{key}.randint needs integers [low, high), got {list(args)}")
