"""Reset seeds: every stage draws its episodes from a stream of its own, so no two stages see the
same scene (docs/controls.md, "Evaluation scenes no other stage has seen").

An env reset with a seed draws its whole scene (goal, markers, object) from it, so two stages that
reset with one seed share a scene: before these streams the anchor sets and the zero-shot episodes
both started at seed 0, and 36 of a study's 60 zero-shot scenes were anchor scenes.

- A training run of seed ``s`` (a source, a grid's cell, a few-shot fine-tuning run) resets from
  ``[s * RUN_STRIDE, (s + 1) * RUN_STRIDE)``: its training episodes from the start of the block
  (counted, so a resumed run draws new ones), its periodic evaluations from ``+EVAL_OFFSET``, its
  final evaluation from ``+FINAL_EVAL_OFFSET``. A co-trained grid of seed ``s`` draws as a run of
  ``s`` does and its grid env resets its ``n`` cells from ``seed * n + i`` (``ps_ray.envs.grid``):
  the block ``[s * n * RUN_STRIDE, (s + 1) * n * RUN_STRIDE)`` (:func:`grid_block`). Every such
  block ends below :data:`FIXED_BASE` while ``s <= MAX_RUN_SEED``; a sweep's run and grid blocks
  are checked apart by ``tests/test_reset_seeds.py`` for every shipped sweep.
- The stages that draw fixed episodes take one block of :data:`BLOCK` seeds each, above every
  run's: :func:`fixed` gives the first reset seed of a stage given its own ``seed`` setting.
  The zero-shot stage scores each training seed's pairs on episodes of their own
  (:func:`fixed_for_run`: :data:`PER_RUN` seeds apart), so that seeds see different scenes and
  an interval over seeds carries the scenes' variance.
"""

from __future__ import annotations

from ps_ray.errors import UserError

RUN_STRIDE = 1_000_003  # a training run's block of reset seeds
EVAL_OFFSET = 500_000  # the periodic evaluations (the stopping rule reads them)
FINAL_EVAL_OFFSET = 700_000  # the final evaluation: episodes the stopping rule never read
RUNNER_STRIDE = 1_000  # each env runner of a run starts this far from the previous one
MAX_RUN_SEED = 99_999  # the largest seed a sweep or a run may name
MAX_GRID_CELLS = 1_000  # far above any grid: (MAX_RUN_SEED + 1) * 1000 * RUN_STRIDE < FIXED_BASE

FIXED_BASE = 1 << 50  # above every run's and grid's block
BLOCK = 1 << 44  # each fixed stream's width
MAX_STAGE_SEED = 1 << 40  # a stage's own seed setting, with its episodes, stays inside its block
PER_RUN = 1_000_000  # a training seed's own episodes of a fixed stream (MAX_RUN_SEED of them fit a BLOCK)

# the stages that draw fixed episodes, in the order of their blocks (append only: a block's place
# is part of every result measured on it)
FIXED_STREAMS = (
    "anchors",  # the anchor sets' task states (and a run's own anchors)
    "fit",  # task states a latent translation is fitted on (resets only)
    "outcomes",  # outcome-matching rollouts of the sources
    "zero_shot",  # the zero-shot episodes of every pair, its controls, chance and floor
    "probes",  # the report's latent probes
    "clips",  # the report's clips
)


def fixed(stream: str, seed: int = 0) -> int:
    """The first reset seed of a fixed stream, given the stage's own ``seed`` setting."""
    if stream not in FIXED_STREAMS:
        raise ValueError(f"unknown reset-seed stream {stream!r}; valid: {', '.join(FIXED_STREAMS)}")
    check_stage_seed(seed, stream)
    return FIXED_BASE + FIXED_STREAMS.index(stream) * BLOCK + seed


def fixed_for_run(stream: str, seed: int, run_seed: int, episodes: int) -> int:
    """The first reset seed of ``episodes`` episodes of a fixed stream that are the training seed
    ``run_seed``'s own (a block of :data:`PER_RUN` per training seed), given the stage's ``seed``."""
    if not 0 <= run_seed <= MAX_RUN_SEED:
        raise UserError(f"bad training seed {run_seed!r}; valid seeds: integers 0..{MAX_RUN_SEED}")
    if episodes > PER_RUN:
        raise UserError(f"{episodes} episodes per training seed; at most {PER_RUN} fit its block")
    return fixed(stream, seed) + run_seed * PER_RUN


def fixed_block(stream: str) -> range:
    """Every reset seed a fixed stream may draw."""
    start = FIXED_BASE + FIXED_STREAMS.index(stream) * BLOCK
    return range(start, start + BLOCK)


def run_block(seed: int) -> range:
    """Every reset seed a training run of ``seed`` may draw (any of its env runners)."""
    return range(seed * RUN_STRIDE, (seed + 1) * RUN_STRIDE)


def run_episode_seed(seed: int | None, episodes: int, *, explore: bool, final: bool = False) -> int:
    """A training run's first reset seed of a call that samples episodes: training episodes by
    their count so far, greedy evaluations at one fixed place, the final one at another."""
    offset = episodes if explore else FINAL_EVAL_OFFSET if final else EVAL_OFFSET
    return (seed or 0) * RUN_STRIDE + offset


def grid_block(seed: int, cells: int) -> range:
    """Every reset seed a co-trained grid of ``seed`` with ``cells`` trained cells may draw."""
    return range(seed * cells * RUN_STRIDE, (seed + 1) * cells * RUN_STRIDE)


def check_stage_seed(seed: object, where: str) -> None:
    """A stage's own seed setting stays inside its block."""
    if isinstance(seed, bool) or not isinstance(seed, int) or not 0 <= seed < MAX_STAGE_SEED:
        raise UserError(f"bad {where} seed {seed!r}; valid seeds: integers 0..{MAX_STAGE_SEED - 1}")
