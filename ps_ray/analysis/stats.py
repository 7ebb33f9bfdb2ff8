"""Aggregate figures a reviewer accepts: mean and IQM over (pair, seed) cells with bootstrap 95%
confidence intervals that resample *seeds* (whole training runs), never episodes.

A cell is one stitched pair (or one compared pair of modules) of one seed. The bootstrap draws
seeds with replacement and keeps every cell of each drawn seed (a cluster bootstrap, so cells of
one seed, which share their source policies, are never treated as independent). Percentile
intervals from ``scipy.stats.bootstrap``; with fewer than two seeds there is no interval (NaN).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
import pandas as pd
from scipy import stats

CONFIDENCE = 0.95
RESAMPLES = 2000


def iqm(values: np.ndarray) -> float:
    """Interquartile mean: the mean of the middle 50% (robust to a few outlier cells)."""
    return float(stats.trim_mean(np.asarray(values, float), 0.25))


STATISTICS = {"mean": lambda v: float(np.mean(v)), "iqm": iqm}


@dataclass(frozen=True)
class Estimate:
    mean: float
    mean_lo: float
    mean_hi: float
    iqm: float
    iqm_lo: float
    iqm_hi: float
    cells: int
    seeds: int

    def text(self, what: str = "mean", digits: int = 2) -> str:
        """``0.32 [0.21, 0.45]`` (point estimate and 95% CI)."""
        point, lo, hi = (getattr(self, f"{what}{s}") for s in ("", "_lo", "_hi"))
        if np.isnan(lo):
            return f"{point:.{digits}f} [n/a]"
        return f"{point:.{digits}f} [{lo:.{digits}f}, {hi:.{digits}f}]"


def estimate(values, seeds, *, seed: int = 0) -> Estimate:
    """Mean and IQM of ``values`` (one per cell) with seed-resampling 95% CIs; ``seeds`` names
    the training seed of each cell."""
    values, seeds = np.asarray(values, float), np.asarray(seeds)
    if values.shape != seeds.shape or values.ndim != 1 or len(values) == 0:
        raise ValueError(f"need one seed per value, got {values.shape} values and {seeds.shape} seeds")
    by_seed = [values[seeds == s] for s in np.unique(seeds)]
    out: dict[str, float] = {}
    for name, fn in STATISTICS.items():
        out[name] = fn(values)
        out[f"{name}_lo"] = out[f"{name}_hi"] = float("nan")
        if len(by_seed) >= 2 and np.ptp(values) > 0:
            drawn = stats.bootstrap(
                (np.arange(len(by_seed)),),
                lambda idx, fn=fn: fn(np.concatenate([by_seed[i] for i in idx])),
                vectorized=False,
                n_resamples=RESAMPLES,
                confidence_level=CONFIDENCE,
                method="percentile",
                rng=np.random.default_rng(seed),
            )
            out[f"{name}_lo"], out[f"{name}_hi"] = map(float, drawn.confidence_interval)
        elif len(by_seed) >= 2:  # every cell equal: the interval is the point
            out[f"{name}_lo"] = out[f"{name}_hi"] = out[name]
    return Estimate(**out, cells=len(values), seeds=len(by_seed))


def estimates(table: pd.DataFrame, value: str, by: str = "method", seed_col: str = "seed") -> pd.DataFrame:
    """One :class:`Estimate` row per ``by`` group of a cell table."""
    rows = [
        {by: key, **asdict(estimate(part[value].to_numpy(), part[seed_col].to_numpy()))}
        for key, part in table.groupby(by, sort=False)
    ]
    return pd.DataFrame(rows).set_index(by) if rows else pd.DataFrame()


def ratio_of_means(numerator, denominator, *, seed: int = 0) -> tuple[float, float, float]:
    """mean(numerator) / mean(denominator) of paired per-seed values (e.g. env steps to a target
    of a method and of its baseline on the same seeds), with a 95% CI from a bootstrap that draws
    seeds, keeping each seed's pair together. Fewer than two seeds: no interval (NaN)."""
    num, den = np.asarray(numerator, float), np.asarray(denominator, float)
    if num.shape != den.shape or num.ndim != 1 or len(num) == 0:
        raise ValueError(f"need paired values, got shapes {num.shape} and {den.shape}")
    point = float(num.mean() / den.mean())
    if len(num) < 2:
        return point, float("nan"), float("nan")
    if np.ptp(num) == 0 and np.ptp(den) == 0:  # every resample gives the point
        return point, point, point
    drawn = stats.bootstrap(
        (num, den),
        lambda n, d, axis=-1: n.mean(axis) / d.mean(axis),
        paired=True,
        vectorized=True,
        n_resamples=RESAMPLES,
        confidence_level=CONFIDENCE,
        method="percentile",
        rng=np.random.default_rng(seed),
    )
    return (point, *map(float, drawn.confidence_interval))
