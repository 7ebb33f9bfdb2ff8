"""Every stage draws its scenes from reset seeds of its own (ps_ray.specs.reset_seeds): anchors,
translation fits, outcome rollouts, training, periodic and final evaluations, grids and zero-shot
episodes never share a scene. Checked on every shipped sweep's seeds, and on the seeds the
stages' own functions reset their envs with."""

from __future__ import annotations

import itertools
from pathlib import Path

import numpy as np
import pytest
import yaml

from ps_ray.envs.core import RobotTaskEnv
from ps_ray.errors import UserError
from ps_ray.specs import reset_seeds
from ps_ray.specs.sweep import SweepSpec, load_sweep

SWEEPS = sorted((Path(__file__).parents[1] / "sweeps").glob("*.yaml"))


def _overlap(a: range, b: range) -> bool:
    return a.start < b.stop and b.start < a.stop


def _blocks(spec: SweepSpec) -> dict[str, range]:
    """Every block of reset seeds the sweep's stages may draw, by who draws it (the trials of one
    seed share a block, as the grids of one seed do: they are the same run's scenes in other envs
    or with another cell held out, all of them training)."""
    blocks = {f"run seed {s}": reset_seeds.run_block(s) for s in sorted({t.seed for t in spec.trials()})}
    if "grid" in spec.stages:
        for grid in spec.grid.grids(spec):
            name = f"grid seed {grid.base.seed} ({len(grid.cells)} cells)"
            blocks[name] = reset_seeds.grid_block(grid.base.seed, len(grid.cells))
    blocks.update({stream: reset_seeds.fixed_block(stream) for stream in reset_seeds.FIXED_STREAMS})
    return blocks


@pytest.mark.parametrize("path", SWEEPS, ids=lambda p: p.stem)
def test_no_two_stages_of_a_shipped_sweep_draw_the_same_reset_seed(path):
    blocks = _blocks(load_sweep(path))
    for (a, first), (b, second) in itertools.combinations(blocks.items(), 2):
        assert not _overlap(first, second), f"{path.name}: {a} and {b} share reset seeds"
    runs = [block for name, block in blocks.items() if name not in reset_seeds.FIXED_STREAMS]
    assert max(b.stop for b in runs) <= reset_seeds.FIXED_BASE  # every run and grid below every fixed stream


def test_a_run_s_training_evaluation_and_final_episodes_stay_in_its_block_and_apart():
    """Training episodes by their count (any env runner), the periodic evaluations at one place,
    the final one at another; the largest seed a spec may name keeps the block below every fixed
    stream, grids of up to 1,000 cells included."""
    for seed in (0, 406, reset_seeds.MAX_RUN_SEED):
        block = reset_seeds.run_block(seed)
        train = reset_seeds.run_episode_seed(seed, 0, explore=True)
        late = reset_seeds.run_episode_seed(seed, 400_000, explore=True) + 8 * reset_seeds.RUNNER_STRIDE
        periodic = reset_seeds.run_episode_seed(seed, 123, explore=False)
        final = reset_seeds.run_episode_seed(seed, 123, explore=False, final=True)
        assert train in block and late in block and periodic in block and final in block
        assert late < periodic < periodic + 8 * reset_seeds.RUNNER_STRIDE + 1_000 < final < block.stop - 1_000
        grid = reset_seeds.grid_block(seed, reset_seeds.MAX_GRID_CELLS)
        assert grid.stop <= reset_seeds.FIXED_BASE


def test_a_sweep_seed_past_the_last_block_is_refused_in_one_line(tmp_path):
    path = tmp_path / "big.yaml"
    spec = yaml.safe_load((Path(__file__).parents[1] / "sweeps" / "smoke.yaml").read_text())
    path.write_text(yaml.safe_dump({**spec, "seeds": [100_000], "storage": str(tmp_path)}))
    with pytest.raises(UserError, match=r"seed must be an integer 0..99999, got 100000"):
        load_sweep(path).trials()


@pytest.fixture
def resets(monkeypatch) -> list[int]:
    """The seed of every env reset from here on (the env itself, unchanged, does the reset)."""
    seen: list[int] = []
    original = RobotTaskEnv.reset

    def recording(self, *, seed=None, options=None):
        seen.append(seed)
        return original(self, seed=seed, options=options)

    monkeypatch.setattr(RobotTaskEnv, "reset", recording)
    return seen


def _drawn(seen: list[int], stream: str) -> None:
    block = reset_seeds.fixed_block(stream)
    assert seen and all(s in block for s in seen), f"{stream}: reset seeds outside its block"


def test_the_stages_functions_reset_from_their_own_streams(resets, tmp_path):
    """The zero-shot episodes (a pair's evaluation, chance and the floor), the outcome rollouts,
    the translation's fit states and the sweep's anchor sets each reset from their own block."""
    from ps_ray.pipeline.anchor_sets import prepare_sweep_anchors
    from ps_ray.pipeline.zero_shot import fit_states
    from ps_ray.stitching.chance import chance
    from ps_ray.stitching.outcomes import outcomes

    first = reset_seeds.fixed("zero_shot", 0)
    chance("panda", "reach_red", {"episodes": 2, "repeats": 1, "seed": first})
    _drawn(resets, "zero_shot")

    resets.clear()
    reach_red = lambda obs: np.zeros((len(obs["robot_state"]), 7))  # noqa: E731
    with pytest.raises(UserError, match="too few to match"):  # a still arm succeeds nowhere
        outcomes(reach_red, "panda", "reach_red", scenes=2)
    _drawn(resets, "outcomes")

    resets.clear()
    fit_states(["reach_red"], 1, reset_seeds.fixed("fit", 0))
    _drawn(resets, "fit")

    resets.clear()
    spec = SweepSpec.from_mapping(
        {
            "name": "anchors",
            "methods": ["ps"],
            "robots": ["panda"],
            "tasks": ["reach_red"],
            "seeds": [0],
            "interface_dims": [4],
            "anchors": {"policy": "random", "episodes": 5},
            "storage": str(tmp_path),
        }
    )
    prepare_sweep_anchors(spec)
    _drawn(resets, "anchors")


def test_each_training_seed_is_scored_on_its_own_zero_shot_episodes_and_a_resume_keeps_only_those():
    """The second confirmation's plan: a pair's episodes are its (task module's) training seed's
    own block of the zero-shot stream, so seeds see different scenes and the pairs of one seed
    share theirs; a resumed stage refuses a kept row scored on other episodes (an older ps_ray)."""
    from ps_ray.plan.catalogue import planned
    from ps_ray.plan.zero_shot import check_kept, pair_episodes, plan, stream_of

    spec = load_sweep(Path(__file__).parents[1] / "sweeps" / "confirm2.yaml")
    pairs, z = plan(spec, planned(spec)), spec.zero_shot
    first = {pair.key: pair_episodes(pair, stream_of(z)).seed for pair in pairs}
    by_seed = {}
    for pair in pairs:
        by_seed.setdefault(pair.seed, set()).add(first[pair.key])
    assert sorted(by_seed) == list(range(411, 419)) and all(len(v) == 1 for v in by_seed.values())
    starts = sorted(next(iter(v)) for v in by_seed.values())
    assert all(b - a >= z.episodes * z.repeats for a, b in zip(starts, starts[1:]))  # disjoint
    assert all(s in reset_seeds.fixed_block("zero_shot") for s in starts)
    pair = pairs[0]
    check_kept({pair.key: {"episodes_seed": first[pair.key]}}, pairs, z)  # its own: kept
    with pytest.raises(UserError, match=f"{pair.key}: its kept zero-shot row was scored on other"):
        check_kept({pair.key: {"success_mean": 0.5}}, pairs, z)  # an older row names none
