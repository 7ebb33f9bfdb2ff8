"""Latent distances, grouping and the report's tables on hand-made inputs."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import torch
from scipy.spatial.distance import cdist
from scipy.stats import special_ortho_group

from ps_ray.analysis import latent, tables
from ps_ray.nets.relative import RelativeProjection
from ps_ray.stitching.pair_table import upgrade


def _dump(values, method="ps", robot="panda", task="reach", seed=1, dim=16):
    key = f"{method}/{robot}/{task}/{seed}"
    return latent.Dump(key, method, robot, task, seed, dim, np.asarray(values, np.float32))


def test_distances_of_identical_interfaces_are_zero():
    x = np.random.default_rng(0).normal(size=(50, 16))
    assert latent.cosine_distance(x, x) == pytest.approx(0.0, abs=1e-12)
    assert latent.l2_distance(x, x) == 0.0


def test_distances_match_the_paper_definitions_row_by_row():
    rng = np.random.default_rng(1)
    a, b = rng.normal(size=(40, 8)), rng.normal(size=(40, 8))
    assert latent.cosine_distance(a, b) == pytest.approx(np.mean(np.diag(cdist(a, b, "cosine"))))
    assert latent.l2_distance(a, b) == pytest.approx(np.mean(np.diag(cdist(a, b))))
    assert latent.cosine_distance(a, -a) == pytest.approx(2.0)


def test_a_rotated_latent_moves_the_raw_interface_but_not_the_relative_one():
    """Two 'networks' whose latents differ by a rotation and a scale (the paper's isometry):
    the raw latents are far apart, their relative vectors against the same anchors coincide."""
    rng = np.random.default_rng(2)
    weight = torch.as_tensor(rng.normal(size=(3, 16)), dtype=torch.float32)
    rotation = torch.as_tensor(special_ortho_group.rvs(16, random_state=3), dtype=torch.float32)
    net_a = lambda x: torch.tanh(x @ weight)  # noqa: E731
    net_b = lambda x: 2.5 * net_a(x) @ rotation  # noqa: E731
    states = torch.as_tensor(rng.uniform(-0.15, 0.15, size=(200, 3)), dtype=torch.float32)
    projection = RelativeProjection(torch.as_tensor(rng.uniform(-0.15, 0.15, (16, 3))))

    raw_cos = latent.cosine_distance(net_a(states).numpy(), net_b(states).numpy())
    rel_a, rel_b = (projection(net, states).detach().numpy() for net in (net_a, net_b))
    assert raw_cos > 0.5
    assert latent.cosine_distance(rel_a, rel_b) < 1e-5
    assert latent.l2_distance(rel_a, rel_b) < 1e-4
    assert latent.l2_distance(net_a(states).numpy(), net_b(states).numpy()) > 1.0


def test_shape_mismatch_is_refused():
    with pytest.raises(ValueError, match=r"one shape, got \(3, 2\) and \(3, 4\)"):
        latent.cosine_distance(np.ones((3, 2)), np.ones((3, 4)))


def test_groups_compare_only_modules_that_differ_in_the_compared_field():
    x = np.eye(4)[:, :3]
    dumps = [_dump(x, seed=s, robot=r) for s in (1, 2, 3) for r in ("panda", "panda_l3")]
    dumps.append(_dump(x, method="ablation", seed=1))  # alone in its group: left out
    by_seed = latent.groups(dumps, "seeds")
    assert [(g.method, g.fixed, list(g.members)) for g in by_seed] == [
        ("ps", "panda, reach", ["1", "2", "3"]),
        ("ps", "panda_l3, reach", ["1", "2", "3"]),
    ]
    by_robot = latent.groups(dumps, "robots")
    assert len(by_robot) == 3 and all(list(g.members) == ["panda", "panda_l3"] for g in by_robot)


def test_distance_table_pools_pairs_and_matrices_are_symmetric():
    rng = np.random.default_rng(4)
    dumps = [_dump(rng.normal(size=(30, 4)), seed=s) for s in (1, 2, 3, 4)]
    (group,) = latent.groups(dumps, "seeds")
    matrix = group.matrix("cosine")
    assert matrix.shape == (4, 4) and np.allclose(matrix, matrix.T) and np.all(np.diag(matrix) == 0)
    table = latent.distance_table([group])
    row = table.iloc[0]
    assert row["pairs"] == 6  # 4 seeds: the paper's 6 pairs
    distinct_pairs = matrix.to_numpy()[np.triu_indices(4, k=1)]
    assert row["cosine_mean"] == pytest.approx(distinct_pairs.mean())
    shown = tables.latent_table(table, "seeds", 16)
    assert list(shown.columns) == [
        "pairs",
        "cosine distance",
        "L2 distance",
        "cosine 95% CI",
        "retrieval MRR [95% CI]",
        "top-1",
    ]
    assert shown.loc["ps", "cosine distance"] == tables.pm(row["cosine_mean"], row["cosine_std"], 4)


def test_zero_shot_table_has_combinations_as_rows_and_methods_as_columns():
    label_e1 = "t: push-panda & r: push_slippery-panda_l3"
    frame = pd.DataFrame(
        [
            {
                "method": m,
                "seed": s,
                "label": label,
                "success_mean": sm,
                "success_std": 0.1,
                "touching_mean": 0.5,
                "touching_std": 0.0,
            }
            for m, sm in (("ablation", 0.2), ("ps", 0.6))
            for s in (1, 2)
            for label in (label_e1, "t: reach-panda & r: reach-panda_l5")
        ]
    )
    frame.loc[(frame["method"] == "ps") & (frame["seed"] == 2), "success_mean"] = 0.8
    table = tables.zero_shot_table(frame)
    assert list(table.columns) == [
        ("ps", "touching"),
        ("ps", "success"),
        ("ablation", "touching"),
        ("ablation", "success"),
    ]
    assert list(table.index) == ["E1 (t: Pu1-R1 & r: Pu2-R2)", "t: reach-panda & r: reach-panda_l5"]
    # mean of the seeds' means; std pooled: sqrt(mean within-seed var + between-seed var)
    assert table.loc["E1 (t: Pu1-R1 & r: Pu2-R2)", ("ps", "success")] == tables.pm(0.7, np.sqrt(0.01 + 0.01))
    assert table.loc["E1 (t: Pu1-R1 & r: Pu2-R2)", ("ablation", "touching")] == "0.50 ± 0.00"
    # reach has nothing to touch: the report blanks touching, and the table leaves it out
    reach = tables.zero_shot_table(frame.assign(touching_mean=float("nan"), touching_std=float("nan")))
    assert list(reach.columns) == [("ps", "success"), ("ablation", "success")]
    # the paper's Table 1 beside ours, for the E-combinations only (E1 here), as fractions
    paper = tables.paper_zero_shot(upgrade(frame, 1))  # as read_table gives it: no control scored
    assert list(paper.index) == [
        ("E1 (t: Pu1-R1 & r: Pu2-R2)", "ps_ray"),
        ("E1 (t: Pu1-R1 & r: Pu2-R2)", "paper"),
    ]
    e1 = paper.loc["E1 (t: Pu1-R1 & r: Pu2-R2)"]
    assert (
        e1.loc["paper", ("ps", "success")] == "0.27 ± 0.04"
        and e1.loc["paper", ("ps", "touching")] == "0.73 ± 0.01"
    )
    assert e1.loc["paper", ("ablation", "success")] == "0.14 ± 0.04"
    assert e1.loc["ps_ray", ("ps", "success")] == table.loc["E1 (t: Pu1-R1 & r: Pu2-R2)", ("ps", "success")]
    assert tables.paper_zero_shot(upgrade(frame[frame["label"] != label_e1], 1)) is None  # no E-combination
    # beside ours, the control the paper lacks: the better unstitched source, our seeds' mean
    controls = tables.paper_zero_shot(upgrade(frame.assign(best_unstitched=frame["seed"] * 0.1 + 0.2), 1))
    e1 = controls.loc["E1 (t: Pu1-R1 & r: Pu2-R2)"]
    assert e1.loc["ps_ray", ("ps", "best unstitched")] == "0.35"  # seeds 1 and 2: 0.3 and 0.4
    assert e1.loc["paper", ("ablation", "best unstitched")] == "not reported"
    assert ("ps", "best unstitched") not in paper.columns  # a table without scored controls: no column


def test_goal_quadrants_follow_the_reach_regions():
    from ps_ray.envs.tasks.reach import GOAL_REGIONS

    for name in latent.QUADRANTS:
        region = GOAL_REGIONS[name]
        assert latent.goal_quadrant(np.asarray(region["center"])) == name


def test_probe_states_are_fixed_and_labelled_by_region():
    probes = latent.probe_states({"name": "reach", "goal_region": "q1"}, per_group=5, seed=3)
    again = latent.probe_states("reach", per_group=5, seed=3)
    assert probes.states.shape == (20, 3) and np.array_equal(probes.states, again.states)
    for state, label in zip(probes.states, probes.labels):
        assert latent.goal_quadrant(state) == label
    push = latent.probe_states("push", per_group=3)
    assert push.states.shape == (12, 15) and sorted(set(push.labels)) == list(latent.QUADRANTS)


def test_steps_to_target_counts_unreached_runs_at_their_last_step():
    rows = []
    for seed, hit in ((1, 3000), (2, 5000), (3, None)):
        for step in range(1000, 8001, 1000):
            success = 0.95 if hit is not None and step >= hit else 0.3
            rows.append(
                {"run": f"ps/{seed}", "method": "ps", "seed": seed, "env_steps": step, "success": success}
            )
            rows.append(
                {
                    "run": f"ablation/{seed}",
                    "method": "ablation",
                    "seed": seed,
                    "env_steps": step,
                    "success": 0.95 if step >= 2000 else 0.0,
                }
            )
    per_run = tables.steps_to_target(pd.DataFrame(rows), 0.9)
    assert per_run.set_index("run").loc["ps/1", "steps"] == 3000
    assert np.isnan(per_run.set_index("run").loc["ps/3", "steps"])
    shown, numbers = tables.steps_to_target_table(per_run, 0.9)
    assert list(numbers.index) == ["ps", "ablation"]
    assert numbers.loc["ps", "reached"] == 2 and numbers.loc["ps", "steps_mean"] == (3000 + 5000 + 8000) / 3
    assert numbers.loc["ablation", "steps_mean"] == 2000 and numbers.loc["ablation", "reached"] == 3
    assert shown.loc["ps", "reached"] == "2/3" and shown.iloc[0, 1].startswith("≥ 5333")


def test_transfer_table_pairs_each_stitched_cell_with_its_controls():
    """Transfer gain per seed = mean over the seed's pairs of stitched - the best of the unstitched
    sources and chance; the controls' columns are their own means; a role that does not apply
    stays out of the best."""
    from ps_ray.analysis.transfer import controls_met, transfer_numbers, transfer_text
    from ps_ray.pipeline.zero_shot import gain

    rows = []
    for seed, shift in ((1, 0.5), (2, 0.6), (3, 0.4)):
        for label in ("a", "b"):
            metrics = {
                "success_mean": shift,
                "robot_source_success": 0.05,
                "task_source_success": np.nan if label == "b" else 0.1,
                "oracle_success": 0.95,
                "chance_success": 0.08,
            }
            rows.append(
                {"method": "ablation", "pairing": "same_seed", "seed": seed, "label": label}
                | metrics
                | gain(metrics)
            )
    table = upgrade(pd.DataFrame(rows), 1)  # as read_table gives it: the other columns NaN
    assert table.loc[1, "best_unstitched"] == 0.05  # label b: only the robot source applies
    assert table.loc[1, "best_control"] == 0.08  # ... and chance is above it
    numbers = transfer_numbers(table).iloc[0]
    assert numbers["gain_diff"] == pytest.approx(np.mean([0.5, 0.6, 0.4]) - np.mean([0.1, 0.08]))
    assert (numbers["gain_wins"], numbers["seeds"], numbers["cells"]) == (3, 3, 6)
    assert numbers["pairs_above_every_control"] == 6 and numbers["oracle_success"] == pytest.approx(0.95)
    assert numbers["chance_success"] == pytest.approx(0.08)
    # a table from before the chance control: the gain over the unstitched sources, chance "–"
    older = table.drop(columns=["chance_success", "best_control"])
    older = upgrade(older.assign(transfer_gain=older["success_mean"] - older["best_unstitched"]), 1)
    old = transfer_numbers(older).iloc[0]
    assert old["gain_diff"] == pytest.approx(np.mean([0.5, 0.6, 0.4]) - np.mean([0.1, 0.05]))
    assert transfer_text(transfer_numbers(older)).iloc[0]["chance (no task knowledge)"] == "–"
    met = controls_met(transfer_numbers(table)).iloc[0]
    assert met["unstitched fail"] and met["oracle learns"]
    shown = transfer_text(transfer_numbers(table))
    gain_column = "transfer gain over every control and the floor (paired over seeds)"
    assert shown.iloc[0][gain_column].endswith("], 3/3 seeds up")  # no p-value at 3 seeds
    assert shown.iloc[0]["task-blind floor (every task, not told which)"].startswith("absent")
    assert shown.iloc[0]["result"] == "label-free"
    # per pair, over its episodes: every stitch beats its best control by 0.3-0.5 at 200 episodes
    # each, and none surely at 4 (where an interval spans about +-0.5)
    surely = "pairs surely above / below every control (95% over a pair's episodes)"
    assert shown.iloc[0][surely] == "–"  # the episodes not given
    assert transfer_text(transfer_numbers(table, 200)).iloc[0][surely] == "6 / 0 of 6 (200 episodes each)"
    assert transfer_text(transfer_numbers(table, 4)).iloc[0][surely] == "0 / 0 of 6 (4 episodes each)"


def test_the_task_blind_floor_raises_the_bar_and_the_old_gain_stays_beside_it():
    """On a family whose tasks share a scene the gain is taken over the floor too; the gain over
    the sources and chance alone stays as a column; an @swapped row is an upper bound, listed last;
    cross-seed rows have their intervals widened for the runs they share and no p-value."""
    from ps_ray.analysis.transfer import transfer_numbers, transfer_text, transfer_views
    from ps_ray.pipeline.zero_shot import gain

    rows = []
    for method in ("ablation+affine@swapped", "ablation+affine@outcome"):
        for pairing in ("cross_seed", "same_seed"):
            for seed, success in ((1, 0.8), (2, 0.7), (3, 0.9), (4, 0.75)):
                metrics = {
                    "success_mean": success,
                    "robot_source_success": 0.0,
                    "task_source_success": 0.05,
                    "oracle_success": 0.95,
                    "chance_success": 0.1,
                    "task_blind_success": 0.5,
                    "wrong_target_mean": 0.1,
                    "task_blind_wrong_target": 0.45,
                    "touching_mean": 0.6,
                    "told_robot_source_success": 0.85,
                    "fit_env_steps": 40_000 if "outcome" in method else 0,
                }
                row = {"method": method, "pairing": pairing, "seed": seed, "label": "a"}
                rows.append(row | metrics | gain(metrics))
    numbers = transfer_numbers(upgrade(pd.DataFrame(rows), 1))
    assert list(numbers["method"])[-2:] == ["ablation+affine@swapped"] * 2  # upper bounds last
    assert list(numbers["pairing"])[::2] == ["same_seed"] * 2  # same seed first within each block
    same = numbers[
        (numbers["method"] == "ablation+affine@outcome") & (numbers["pairing"] == "same_seed")
    ].iloc[0]
    assert same["gain_diff"] == pytest.approx(0.7875 - 0.5)  # over the floor
    assert same["chance_gain_diff"] == pytest.approx(0.7875 - 0.1)  # over chance, as before
    assert same["wrong_target_mean"] == pytest.approx(0.1)
    assert same["task_blind_wrong_target"] == pytest.approx(0.45) and same["touching_mean"] == pytest.approx(
        0.6
    )
    cross = numbers[
        (numbers["method"] == "ablation+affine@outcome") & (numbers["pairing"] == "cross_seed")
    ].iloc[0]
    assert (
        np.isnan(cross["gain_p"]) and cross["gain_hi"] - cross["gain_lo"] > same["gain_hi"] - same["gain_lo"]
    )
    shown = transfer_text(numbers)
    assert shown.loc[("ablation+affine@swapped", "same_seed"), "result"] == "upper bound (reads the target)"
    assert shown.loc[("ablation+affine@outcome", "same_seed"), "env steps of the fit per stitch"] == "40,000"
    assert shown.loc[("ablation+affine@outcome", "same_seed"), "wrong target (floor)"].startswith("0.45 [")
    controls, gains = transfer_views(numbers)
    assert list(controls.columns)[-4:] == [
        "ceiling: robot source told the task (a perfect map)",
        "wrong target (stitched)",
        "wrong target (floor)",
        "touching (stitched)",
    ]
    assert same["told_robot_source_success"] == pytest.approx(0.85)
    untold = transfer_views(numbers.assign(told_robot_source_success=np.nan))[0]
    assert not any(c.startswith("ceiling") for c in untold.columns)  # no pair has a ceiling
    # a stage resumed across the ceiling's arrival: kept rows lack it, and the table says so
    resumed = upgrade(pd.DataFrame(rows).assign(told_robot_source_success=[0.85, np.nan] * 8), 1)
    ceiling = "ceiling: robot source told the task (a perfect map)"
    partial = transfer_text(transfer_numbers(resumed)).loc[("ablation+affine@outcome", "same_seed"), ceiling]
    assert partial.startswith("0.85 [") and partial.endswith("(on 2 of 4 cells)")
    assert "touching (stitched)" not in transfer_views(numbers, touching=False)[0]  # reach: nothing to touch
    assert list(gains.columns)[:2] == ["result", "seeds"]
    cross_shown = shown.loc[("ablation+affine@outcome", "cross_seed")]
    assert (
        "units share runs"
        in cross_shown["transfer gain over every control and the floor (paired over seeds)"]
    )


def test_few_shot_table_pairs_each_start_with_scratch_on_steps_and_area():
    """Per start: env steps to 0.8 and the area under the success curve, each paired with scratch
    on the same target and seed; a run that never reaches 0.8 counts at its last step."""
    from ps_ray.analysis.transfer import curve_area, few_shot_steps

    rows = []
    for seed in (1, 2, 3):
        for kind, curve in (
            ("stitched", [0.5, 0.9, 1.0, 1.0]),
            ("robot_module", [0.0, 0.2, 0.8, 1.0]),
            ("scratch", [0.0, 0.0, 0.4, 0.6]),
        ):
            for step, success in zip((1000, 2000, 3000, 4000), curve):
                rows.append(
                    {"run": f"{kind}/{seed}", "kind": kind, "method": "ablation", "robot": "panda"}
                    | {"task": "reach_red", "seed": seed, "env_steps": step, "success": success}
                )
    curves = pd.DataFrame(rows)
    assert curve_area(curves[curves["run"] == "stitched/1"]) == pytest.approx(
        (0.7 + 0.95 + 1.0) * 1000 / 3000
    )
    table = few_shot_steps(curves, 0.8)
    stitched, half, scratch = (table.loc[(k, "ablation")] for k in ("stitched", "robot_module", "scratch"))
    assert stitched["reached 0.8"] == "3/3" and scratch["reached 0.8"] == "0/3"
    assert stitched["env steps to 0.8 [95% CI]"].startswith("2000")
    assert scratch["env steps to 0.8 [95% CI]"].startswith("4000")  # never reached: its last step
    assert stitched["env steps to 0.8: minus scratch (paired over seeds)"].startswith("-2000")
    assert half["area under curve: minus scratch (paired over seeds)"].startswith("+0.27")
    assert scratch["area under curve: minus scratch (paired over seeds)"] == "–"
    # a run stopped at its target (here after 2,000 steps at 1.0) keeps that success to the budget
    early = curves[curves["run"] == "stitched/1"].iloc[:2].assign(success=[0.5, 1.0])
    assert curve_area(early, 4000) == pytest.approx((0.75 * 1000 + 1.0 * 2000) / 3000)
    stopped = pd.concat([curves[curves["run"] != "stitched/1"], early.assign(kind="stitched")])
    assert (
        few_shot_steps(stopped, 0.8)
        .loc[("stitched", "ablation"), "area under curve [95% CI]"]
        .startswith(
            "0.89"  # (0.917 + 0.883 x 2) / 3: the stopped run counts 0.917 over the whole budget, not 0.75
        )
    )


def test_few_shot_curves_are_means_over_seeds_with_their_t_interval_and_stopped_runs_held():
    """The few-shot figure's numbers: a seed's runs averaged first, then mean and t interval (logit) over
    seeds; a run stopped at its target keeps its last success to the budget; steps some seed has
    not reached yet are left out."""
    from ps_ray.analysis.stats import t_interval
    from ps_ray.analysis.transfer import seed_curves

    rows = []
    for seed, pairs in ((1, ([0.2, 0.6, 1.0], [0.0, 0.4, 0.8])), (2, ([0.4, 1.0], [0.2, 0.2, 0.6]))):
        for pair, curve in enumerate(pairs):  # seed 2's first run stopped at 1.0 after 2,000 steps
            for step, success in zip((1000, 2000, 3000), curve):
                rows.append(
                    {"run": f"s{seed}p{pair}", "kind": "stitched", "method": "ablation", "seed": seed}
                    | {"env_steps": step, "success": success}
                )
    rows.append(
        {"run": "late", "kind": "scratch", "method": "ablation", "seed": 1, "env_steps": 2000, "success": 0.5}
    )
    rows.append(
        {"run": "late", "kind": "scratch", "method": "ablation", "seed": 1, "env_steps": 3000, "success": 0.7}
    )
    table = seed_curves(pd.DataFrame(rows)).set_index(["kind", "env_steps"])
    at_3000 = table.loc[("stitched", 3000)]
    # seed 1: (1.0 + 0.8) / 2; seed 2: (1.0 held + 0.6) / 2
    assert at_3000["mean"] == pytest.approx((0.9 + 0.8) / 2)
    assert (at_3000["low"], at_3000["high"]) == pytest.approx(t_interval([0.9, 0.8], rate=True)[1:])
    assert 0 < at_3000["low"] < at_3000["high"] < 1  # a success rate's interval stays inside (0, 1)
    assert table.loc[("stitched", 1000), "mean"] == pytest.approx((0.1 + 0.3) / 2)
    assert at_3000["seeds"] == 2
    scratch = table.loc["scratch"]  # one seed: a mean, no interval, and nothing before its first evaluation
    assert list(scratch.index) == [2000, 3000] and np.isnan(scratch["low"]).all()


def test_task_variants_are_named_as_a_reader_would_in_tables_and_plots():
    from ps_ray.specs.names import readable

    assert readable('t: reach{"goal_region":"q1"}-panda_l3 & r: reach{"goal_region":"q3"}-panda') == (
        "t: reach q1-panda_l3 & r: reach q3-panda"
    )
    assert readable('push{"friction":0.1,"rocks":true}') == "push friction=0.1 rocks=true"
    assert readable("ps/panda/reach_red/401") == "ps/panda/reach_red/401"  # no variant: unchanged
    assert readable("x{not json}") == "x{not json}"


def test_a_sections_text_sets_backticked_names_as_code_and_escapes_the_rest():
    from ps_ray.analysis.page import prose

    assert prose("run `ps-ray demo` <now>") == "run <code>ps-ray demo</code> &lt;now&gt;"
    assert "`" not in prose("`a` and `b@c`") and prose("`a` and `b@c`").count("<code>") == 2


def test_the_few_shot_figure_draws_its_targets_floor_and_oracle_from_the_same_seeds_zero_shot_pairs():
    from ps_ray.analysis.plots import seed_interval_figure
    from ps_ray.analysis.transfer import few_shot_references, seed_curves

    far = 'panda_far{"base_offset":0.1}'  # a mapping robot: its short name here, its spec text there
    curves = pd.DataFrame(
        [
            {"run": run, "kind": kind, "method": "ablation", "robot": far, "task": task, "seed": 7}
            | {"env_steps": 1000, "success": 0.1}
            for run, kind, task in (("a", "stitched", "push_blue"), ("b", "scratch", "push_red"))
        ]
    )
    robot_text = '{"base_offset": 0.1, "name": "panda_far"}'
    pair = {"method": "ablation", "pairing": "same_seed", "robot": robot_text, "seed": 7}
    zero_shot = pd.DataFrame(
        [
            pair | {"task": "push_blue", "task_blind_success": 0.3, "oracle_success": 0.6},
            pair | {"task": "push_blue", "task_blind_success": 0.3, "oracle_success": 0.6},  # 2 pairs
            pair | {"task": "push_red", "task_blind_success": 0.2, "oracle_success": 0.4},
            # none of these is the few-shot runs' target and method, seed and pairing
            pair | {"task": "push_red", "seed": 8, "task_blind_success": 0.9, "oracle_success": 0.9},
            pair
            | {"task": "push_red", "pairing": "cross_seed", "task_blind_success": 0.9, "oracle_success": 0.9},
            pair | {"task": "push_red", "method": "ps", "task_blind_success": 0.9, "oracle_success": 0.9},
            pair
            | {"task": "push_red", "robot": "panda_far", "task_blind_success": 0.9, "oracle_success": 0.9},
        ]
    )
    levels = few_shot_references(curves, zero_shot)
    # each target once, however many pairs it has: (0.3 + 0.2) / 2 and (0.6 + 0.4) / 2
    assert levels["ablation"] == pytest.approx(
        {
            "task-blind floor (zero-shot), mean of 2 targets": 0.25,
            "oracle (trained on the target), mean of 2 targets": 0.5,
        }
    )
    one = few_shot_references(curves[curves["task"] == "push_red"], zero_shot)["ablation"]
    assert one == pytest.approx({"task-blind floor (zero-shot)": 0.2, "oracle (trained on the target)": 0.4})
    assert few_shot_references(curves, None) == {}
    assert few_shot_references(curves.assign(seed=9), zero_shot) == {}  # no pair of these targets

    (ax,) = seed_interval_figure(seed_curves(curves), "few-shot", references=levels).axes
    legend = [t.get_text() for t in ax.get_legend().get_texts()]
    assert legend == [
        "stitch as it is (1 seed)",
        "scratch (1 seed)",
        "task-blind floor (zero-shot), mean of 2 targets: 0.25",
        "oracle (trained on the target), mean of 2 targets: 0.50",
    ]
    levels_drawn = [line.get_ydata()[0] for line in ax.get_lines() if line.get_color() == "0.35"]
    assert levels_drawn == pytest.approx([0.25, 0.5])


def test_every_transfer_gain_bar_says_its_value_so_a_zero_gain_or_a_missing_pair_still_reads():
    from ps_ray.analysis.transfer_plots import transfer_gain_figure

    rows = [
        ("ps", "same_seed", "t: a & r: b", 0.25),
        ("ps", "same_seed", "t: a & r: b", 0.35),
        ("ps", "same_seed", "t: b & r: a", 0.0),  # a gain of 0 draws no bar
        ("ablation", "same_seed", "t: a & r: b", -0.5),  # ablation never stitched t: b & r: a
        ("ablation", "cross_seed", "t: a & r: b", -0.4),  # ps has no cross-seed pair
    ][::-1]  # same seed's panel first, whichever pairing the table lists first
    table = pd.DataFrame(rows, columns=["method", "pairing", "label", "transfer_gain"])
    fig = transfer_gain_figure(table)
    same, cross = fig.axes
    assert [t.get_text() for t in same.texts] == ["+0.30", "-0.50", "+0.00"]
    # a method stitched in one pairing but not the other says so; one never stitched is not drawn
    assert [t.get_text() for t in cross.texts] == ["no pairs", "-0.40", "no pairs"]
    assert "task-blind floor" in same.get_xlabel()
    # each value stands right of its bar's error bar (or of 0), on its bar's row; a blank row
    # parts the combinations, each labelled at its bars' middle
    ys = {t.get_text(): t.get_position() for t in same.texts}
    assert ys["+0.30"][0] == pytest.approx(0.38) and ys["-0.50"][0] == pytest.approx(0.03)
    assert [ys[v][1] for v in ("+0.30", "-0.50", "+0.00")] == [0, 1, 3]
    assert list(same.get_yticks()) == [0.5, 3.0]
    assert [t.get_text() for t in same.get_yticklabels()] == ["t: a & r: b", "t: b & r: a"]
    # the legend names every method and stands above the panels, over no bar
    (legend,) = fig.legends
    assert [t.get_text() for t in legend.get_texts()] == ["ps", "ablation"]
    fig.canvas.draw()
    renderer = fig.canvas.get_renderer()
    assert legend.get_window_extent(renderer).y0 >= same.get_window_extent(renderer).y1


def test_the_controls_figure_puts_same_seed_first_upper_bounds_last_and_leaves_out_controls_not_run():
    from matplotlib.colors import to_rgb

    from ps_ray.analysis.transfer_plots import CONTROL_BARS, controls_figure

    rows = [
        ("ablation", "cross_seed", False, 0.1),  # listed first, drawn in the second panel
        ("ablation+affine@swapped", "same_seed", True, 0.4),
        ("ablation", "same_seed", False, 0.2),
        ("ablation co-trained", "same_seed", False, 0.45),  # no cross-seed pairs
    ]
    numbers = pd.DataFrame(rows, columns=["method", "pairing", "upper_bound", "success_mean"])
    for column, _ in CONTROL_BARS[1:]:
        numbers[column] = 0.3
    numbers["told_robot_source_success"] = np.nan  # the ceiling was not run
    for column, _ in CONTROL_BARS:
        numbers[f"{column}_lo"], numbers[f"{column}_hi"] = numbers[column] - 0.1, numbers[column] + 0.1
    fig = controls_figure(numbers)
    same, cross = fig.axes
    assert (same.get_title(), cross.get_title()) == ("same seed", "cross seed")
    names = [t.get_text() for t in same.get_yticklabels()]
    assert names == ["ablation", "ablation co-trained", "ablation+affine@swapped"]
    (legend,) = fig.legends
    assert "ceiling: robot source told the task" not in [t.get_text() for t in legend.get_texts()]
    assert [t.get_text() for t in legend.get_texts()][0] == "stitched"
    # the stitched bar of each row is its method's success in that panel; a row without pairs says so
    stitched = sorted(
        (p for p in same.patches if p.get_facecolor()[:3] == to_rgb("C0")), key=lambda p: p.get_y()
    )
    assert [round(p.get_width(), 2) for p in stitched] == [0.2, 0.45, 0.4]
    assert [t.get_text() for t in cross.texts] == ["no pairs", "no pairs"]


def test_the_headline_gives_success_per_pairing_where_a_method_was_scored_beside_its_controls(tmp_path):
    """A co-trained grid's held-out cell transfers within its seed and not across: the headline
    shows each pairing's success (same seed first), not their pooled mean; a method whose pairs
    were scored without controls (no gain) keeps the pooled mean and IQM."""
    from ps_ray.analysis.page import Report
    from ps_ray.analysis.summary import summary_section
    from ps_ray.specs.sweep import load_sweep

    spec = load_sweep(Path(__file__).parents[1] / "sweeps" / "push_family.yaml")
    report = Report(tmp_path)
    (tmp_path / "tables").mkdir()
    pooled = {"success_mean": 0.23, "success_mean_lo": 0.2, "success_mean_hi": 0.3, "success_iqm": 0.2}
    report.headline.zero_shot = pd.DataFrame(
        [pooled | {"success_cells": 6}, pooled | {"success_cells": 24}],
        index=["ablation co-trained", "ablation"],
    )
    gain = {"gain_diff": 0.19, "gain_lo": 0.03, "gain_hi": 0.36, "gain_p": np.nan, "seeds": 3}
    report.headline.transfer = pd.DataFrame(
        [
            {"method": "ablation co-trained", "pairing": "cross_seed", "success_mean": 0.003}
            | {"success_mean_lo": 0.0, "success_mean_hi": 0.1}
            | gain,
            {"method": "ablation co-trained", "pairing": "same_seed", "success_mean": 0.45}
            | {"success_mean_lo": 0.36, "success_mean_hi": 0.55}
            | gain,
            {"method": "ablation", "pairing": "same_seed", "success_mean": 0.23}
            | {"success_mean_lo": 0.2, "success_mean_hi": 0.3}
            | gain
            | {"gain_diff": np.nan},
        ]
    )
    summary_section(report, spec, target=0.9)
    headline = pd.read_csv(tmp_path / "tables" / "summary.csv", index_col="method")
    co_trained, alone = headline.loc["ablation co-trained"], headline.loc["ablation"]
    assert co_trained["zero-shot success, same seed [95% CI]"] == "0.45 [0.36, 0.55]"
    assert co_trained["zero-shot success, cross seed [95% CI]"] == "0.00 [0.00, 0.10]"
    assert co_trained["zero-shot success, mean [95% CI]"] == "–"  # no pooled mean beside them
    assert alone["zero-shot success, mean [95% CI]"] == "0.23 [0.20, 0.30]"
    assert alone["zero-shot success, same seed [95% CI]"] == "–"
    columns = list(headline.columns)
    assert columns.index("transfer gain, same seed") < columns.index("transfer gain, cross seed")
    report.headline.transfer = None  # a sweep whose zero-shot stage scored no controls at all
    summary_section(report, spec, target=0.9)
    headline = pd.read_csv(tmp_path / "tables" / "summary.csv", index_col="method", dtype=str)
    assert headline.loc["ablation co-trained", "zero-shot success, mean [95% CI]"] == "0.23 [0.20, 0.30]"
    assert not any("same seed" in column for column in headline.columns)
