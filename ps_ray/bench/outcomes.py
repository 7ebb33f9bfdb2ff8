"""How many outcome scenes a translation fitted on outcome-matched pairs needs, and what they cost.

For the stitched pairs of a finished zero-shot stage whose translation is ``affine@outcome``, the
fit is redone from the first N outcome scenes of each source (N of ``--scenes``; the smaller sets
are prefixes of the larger, the same reset seeds) with each latent map of ``--fits`` (default:
the ridge fit and the plain least squares it replaced) and the stitch is scored on the stage's
own zero-shot episodes of the pair's seed. Prints per N: the fit's env steps, per fit the
stitched success (mean over pairs, t interval over seeds) and the median ridge strength chosen,
and the wall time. No Ray, no MLflow; the sources' outcome rollouts go to (and come from) the
sweep's own outcome cache (``<sweep>/outcomes``, keyed by file, env and scene count), so the
stage's 400 are not rolled out again and a second run of the bench rolls out nothing.

    ps-ray bench outcomes runs/sweeps/confirm [--scenes 25 50 100 200 400 800] [--pairs-per-seed 1]
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pandas as pd

from ps_ray.cli.args import Parser, positive_int
from ps_ray.errors import UserError
from ps_ray.specs.modes import Pairing


def run(
    sweep: Path,
    scenes: Sequence[int],
    pairs_per_seed: int,
    fits: Sequence[str] = ("affine", "affine_lstsq"),
    fit: str = "outcome",
    seeds: Sequence[int] | None = None,
) -> pd.DataFrame:
    from ps_ray.analysis.stats import estimate
    from ps_ray.nets.policy_file import load_policy
    from ps_ray.plan.zero_shot import pair_episodes, stream_of
    from ps_ray.specs.sweep import load_stored_sweep
    from ps_ray.stitching.evaluate import evaluate
    from ps_ray.stitching.outcomes import fit_env_steps, fit_pairs
    from ps_ray.stitching.pair_table import pairs_from_table
    from ps_ray.stitching.stitch import stitch_policies, translation_ridge

    table = sweep / "zero_shot.csv"
    found = pairs_from_table(table)
    if not found:
        raise UserError(f"{table}: no zero-shot table with its pairs' files; run the zero-shot stage first")
    spec = load_stored_sweep(sweep / "sweep.yaml")
    chosen, taken = [], {}
    for pair in found:
        if pair.translation and (pair.translation.kind, pair.translation.fit) == ("affine", fit):
            wanted = seeds is None or pair.seed in seeds
            if wanted and taken.get(pair.seed, 0) < pairs_per_seed and pair.pairing == Pairing.SAME_SEED:
                taken[pair.seed] = taken.get(pair.seed, 0) + 1
                chosen.append(pair)
    if not chosen:
        raise UserError(f"{table}: no same-seed affine@{fit} pairs; valid: a sweep that translates with it")
    z = spec.zero_shot
    pair_seeds = np.array([pair.seed for pair in chosen])
    rows = []
    for n in scenes:
        started = time.perf_counter()
        row: dict = {"outcome scenes": n, "fit env steps per stitch": fit_env_steps("affine", fit, n)}
        success = {kind: [] for kind in fits}
        ridges = []
        for pair in chosen:
            try:
                states = fit_pairs(fit, *pair.sources, n, z.outcome_points, z.seed, str(sweep / "outcomes"))
            except UserError:  # too few successful outcomes at this N: the fit cannot be made
                states = None
            for kind in fits:
                if states is None:
                    success[kind].append(np.nan)
                    continue
                nets = stitch_policies(
                    load_policy(pair.task_from_path),
                    load_policy(pair.robot_from_path),
                    translation=kind,
                    fit_states=states,
                )
                episodes = pair_episodes(pair, stream_of(z)).kwargs()
                success[kind].append(evaluate(nets, pair.robot, pair.task, **episodes)["success_mean"])
                if kind == "affine":
                    ridges.append(translation_ridge(nets[0]))
        for kind in fits:
            values = np.array(success[kind])
            made = ~np.isnan(values)
            e = estimate(values[made], pair_seeds[made], rate=True) if made.any() else None
            row["pairs fitted"] = f"{int(made.sum())}/{len(values)}"
            row[f"{kind} stitched [95% CI over seeds]"] = "–" if e is None else e.text()
        if ridges:
            row["ridge chosen (median)"] = f"{np.median(ridges):.2g}"
        row["wall s"] = round(time.perf_counter() - started, 1)
        rows.append(row)
        print(f"[outcomes] {n} scenes: " + ", ".join(f"{k} {v}" for k, v in row.items()), flush=True)
    return pd.DataFrame(rows)


def main(argv: Sequence[str] | None = None) -> None:
    parser = Parser(prog="ps-ray bench outcomes", description=(__doc__ or "").splitlines()[0])
    parser.add_argument("sweep", type=Path, help="a sweep folder whose zero-shot stage finished")
    parser.add_argument("--scenes", type=positive_int, nargs="+", default=[25, 50, 100, 200, 400, 800])
    parser.add_argument("--pairs-per-seed", type=positive_int, default=1, help="same-seed pairs per seed")
    parser.add_argument("--seeds", type=int, nargs="+", default=None, help="only these training seeds")
    parser.add_argument(
        "--fits",
        nargs="+",
        choices=["affine", "affine_lstsq"],
        default=["affine", "affine_lstsq"],
        help="the latent maps to refit (affine: ridge, cross-validated; affine_lstsq: plain least squares)",
    )
    args = parser.parse_args(argv)
    out = run(args.sweep, sorted(args.scenes), args.pairs_per_seed, args.fits, seeds=args.seeds)
    print(f"affine@outcome refitted on the first N outcome scenes of each source ({args.sweep})")
    print(out.to_string(index=False))
