"""How many outcome scenes a translation fitted on outcome-matched pairs needs, and what they cost.

For the stitched pairs of a finished zero-shot stage whose translation is ``<kind>@outcome``, the
fit is redone from the first N outcome scenes of each source (N of ``--scenes``; the smaller sets
are prefixes of the larger, the same reset seeds) and the stitch is scored on the stage's own
zero-shot episodes. Prints per N: the fit's env steps, the stitched success (mean over pairs, t
interval over seeds) and the wall time; no Ray, no MLflow, nothing written.

    ps-ray bench outcomes runs/sweeps/confirm [--scenes 25 50 100 400] [--pairs-per-seed 1]
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pandas as pd
import yaml

from ps_ray.cli.args import Parser, positive_int
from ps_ray.errors import UserError


def run(sweep: Path, scenes: Sequence[int], pairs_per_seed: int, fit: str = "outcome") -> pd.DataFrame:
    from ps_ray.analysis.stats import estimate
    from ps_ray.nets.policy_file import load_policy
    from ps_ray.specs import reset_seeds
    from ps_ray.specs.names import split_translation
    from ps_ray.specs.sweep import SweepSpec
    from ps_ray.stitching.evaluate import evaluate
    from ps_ray.stitching.outcomes import fit_env_steps, fit_pairs
    from ps_ray.stitching.pairs import pairs_from_table
    from ps_ray.stitching.stitch import stitch_policies

    table = sweep / "zero_shot.csv"
    found = pairs_from_table(table)
    if not found:
        raise UserError(f"{table}: no zero-shot table with its pairs' files; run the zero-shot stage first")
    spec = SweepSpec.from_mapping(yaml.safe_load((sweep / "sweep.yaml").read_text()), where=str(sweep))
    chosen, taken = [], {}
    for pair in found:
        if pair.translation and split_translation(pair.translation) == ("affine", fit):
            if taken.get(pair.seed, 0) < pairs_per_seed and pair.pairing == "same_seed":
                taken[pair.seed] = taken.get(pair.seed, 0) + 1
                chosen.append(pair)
    if not chosen:
        raise UserError(f"{table}: no same-seed affine@{fit} pairs; valid: a sweep that translates with it")
    z = spec.zero_shot
    episodes = {"episodes": z.episodes, "repeats": z.repeats, "seed": reset_seeds.fixed("zero_shot", z.seed)}
    rows = []
    for n in scenes:
        started = time.perf_counter()
        success, seeds = [], []
        for pair in chosen:
            try:
                states = fit_pairs(fit, *pair.sources, n, z.outcome_points, z.seed)
            except UserError:  # too few successful outcomes at this N: the fit cannot be made
                success.append(np.nan)
                seeds.append(pair.seed)
                continue
            nets = stitch_policies(
                load_policy(pair.task_from_path),
                load_policy(pair.robot_from_path),
                translation="affine",
                fit_states=states,
            )
            success.append(evaluate(nets, pair.robot, pair.task, **episodes)["success_mean"])
            seeds.append(pair.seed)
        values, seeds = np.array(success), np.array(seeds)
        made = ~np.isnan(values)
        e = estimate(values[made], seeds[made]) if made.any() else None
        rows.append(
            {
                "outcome scenes": n,
                "fit env steps per stitch": fit_env_steps("affine", fit, n),
                "pairs fitted": f"{int(made.sum())}/{len(values)}",
                "stitched success [95% CI over seeds]": "–" if e is None else e.text(),
                "wall s": round(time.perf_counter() - started, 1),
            }
        )
    return pd.DataFrame(rows)


def main(argv: Sequence[str] | None = None) -> None:
    parser = Parser(prog="ps-ray bench outcomes", description=(__doc__ or "").splitlines()[0])
    parser.add_argument("sweep", type=Path, help="a sweep folder whose zero-shot stage finished")
    parser.add_argument("--scenes", type=positive_int, nargs="+", default=[25, 50, 100, 400])
    parser.add_argument("--pairs-per-seed", type=positive_int, default=1, help="same-seed pairs per seed")
    args = parser.parse_args(argv)
    out = run(args.sweep, sorted(args.scenes), args.pairs_per_seed)
    print(f"affine@outcome refitted on the first N outcome scenes of each source ({args.sweep})")
    print(out.to_string(index=False))
