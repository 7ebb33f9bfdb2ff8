"""Aggregate figures a reviewer accepts at the small seed counts of RL studies (docs/statistics.md).

A cell is one stitched pair (or one compared pair of modules) of one seed. Seeds (whole training
runs) are the unit of replication: the cells of one seed share their source policies, so they are
first averaged per seed, and the interval is a Student t interval over the n per-seed means
(df = n - 1). It keeps its coverage at n = 3 (tested by simulation), where a percentile bootstrap
over seeds returns [min, max] of the seed means and covers about 75%. Paired comparisons (one
method against another on the same cells) take per-seed mean differences, their t interval and an
exact sign-flip permutation p-value. The IQM is given as a point; its seed-bootstrap interval only
from ``BOOTSTRAP_MIN_SEEDS`` seeds on. Fewer than two seeds: no interval (NaN).

Cross-seed units share runs (unit i: run i's task module with run i+1's robot module, cyclically),
so neighbouring units are correlated; ``shared_runs=True`` widens the interval for the worst case
that sharing allows (:func:`shared_runs_factor`) and gives no sign-flip p-value (it assumes
independent units).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
import pandas as pd
from scipy import special, stats

CONFIDENCE = 0.95
RESAMPLES = 2000
# the fewest seeds at which the sign-flip test can reach p < 0.05 (its floor is 2 / 2^n); below
# it a comparison is said as seeds up, never as a p-value
SIGN_TEST_MIN_SEEDS = 6
BOOTSTRAP_MIN_SEEDS = 10  # rliable's advice; below it a percentile bootstrap over seeds undercovers


def shared_runs_factor(n: int) -> float:
    """How much wider a t interval over ``n`` cyclic cross-seed units must be to keep its coverage
    whatever the runs they share contribute (docs/statistics.md, "Units that share runs").

    Unit i is g(X_i, Y_{i+1}) of run i's task half and run i+1's robot half; only neighbours share
    a run. By the Hoeffding decomposition their covariance is cov(B(Y_j), A(X_j)) of the two
    halves' main effects in the shared run j, at most sqrt(var A var B) <= var(u) / 2: the
    correlation of neighbours is rho <= 1/2. Then var(mean) = var(u) (1 + 2 rho) / n and the
    sample variance's expectation is var(u) (1 - 2 rho / (n - 1)); at rho = 1/2 the standard error
    grows by sqrt(2 (n - 1) / (n - 2)). Fewer than three units: no interval (they share every run)."""
    return float(np.sqrt(2 * (n - 1) / (n - 2))) if n >= 3 else float("nan")


def t_interval(
    values, confidence: float = CONFIDENCE, shared_runs: bool = False, rate: bool = False
) -> tuple[float, float, float]:
    """Mean and Student t interval (df = n - 1) of values one per seed: independent, or with
    ``shared_runs`` cyclic cross-seed units, widened by :func:`shared_runs_factor` with df = n - 2
    (at the worst case the sharing allows it covers 0.95-0.96 at n = 3..8 in simulation, where
    the plain interval covers 0.81-0.84; docs/statistics.md).

    ``rate``: the values are rates in [0, 1] (success), and the interval is taken on the logit
    scale around the mean (its standard error carried over by the delta method, then mapped
    back), so it stays inside (0, 1) and is asymmetric near the ends. Seed means near 0.9 from
    60 episodes each: it covers 0.95 at n = 3, 5 and 8 in simulation, where the plain interval
    covers 0.92-0.93 and passes 1 at n = 3 and 5 in most draws (tests/test_stats.py)."""
    x = np.asarray(values, float)
    mean = float(x.mean()) if len(x) else float("nan")
    if len(x) < 2:
        return mean, float("nan"), float("nan")
    df = len(x) - 2 if shared_runs else len(x) - 1  # shared: one df fewer keeps the coverage (simulated)
    if df < 1:
        return mean, float("nan"), float("nan")
    half = float(stats.t.ppf(0.5 + confidence / 2, df) * x.std(ddof=1) / np.sqrt(len(x)))
    if shared_runs:
        half *= shared_runs_factor(len(x))
    if not rate or half == 0 or mean != mean:
        return mean, mean - half, mean + half
    if not 0 < mean < 1:  # a rate's mean at 0 or 1 has every value there: half is 0
        raise ValueError(f"rates must lie in [0, 1], got a mean of {mean}")
    centre, half_logit = special.logit(mean), half / (mean * (1 - mean))
    return mean, float(special.expit(centre - half_logit)), float(special.expit(centre + half_logit))


def sign_flip_p(differences) -> float:
    """Two-sided exact permutation p-value of a zero mean difference (signs flipped at random; all
    2^n flips up to n = 16, else 20,000 drawn). Its floor is 2 / 2^n: at n = 5 no result reaches
    p < 0.05, which is why a claim needs at least 6 seeds to be significant by this test."""
    d = np.asarray(differences, float)
    n = len(d)
    if n == 0 or not np.any(d):
        return 1.0
    if n <= 16:
        signs = 1 - 2 * ((np.arange(2**n)[:, None] >> np.arange(n)) & 1)
    else:
        signs = np.random.default_rng(0).choice([-1, 1], size=(20000, n))
    flipped = np.abs((signs * d).mean(axis=1))
    return float(np.mean(flipped >= abs(d.mean()) - 1e-12))


@dataclass(frozen=True)
class Paired:
    """A paired comparison over seeds: the per-seed mean differences ``a - b``."""

    diff: float
    lo: float
    hi: float
    p: float  # exact sign-flip permutation p-value
    seeds: int
    wins: int  # seeds where a > b
    losses: int

    def text(self, digits: int = 2) -> str:
        """``+0.12 [0.03, 0.21], p 0.03, 6/6 seeds up``; below :data:`SIGN_TEST_MIN_SEEDS` seeds
        no p-value (it cannot reach 0.05 there): ``+0.12 [0.03, 0.21], 5/5 seeds up``."""
        if self.seeds < 2 or np.isnan(self.lo):
            return f"{self.diff:+.{digits}f} [n/a: {self.seeds} seed{'s' * (self.seeds != 1)}]"
        p = "" if np.isnan(self.p) or self.seeds < SIGN_TEST_MIN_SEEDS else f"p {self.p:.2g}, "
        return (
            f"{self.diff:+.{digits}f} [{self.lo:+.{digits}f}, {self.hi:+.{digits}f}], "
            f"{p}{self.wins}/{self.seeds} seeds up"
        )


def paired(a, b, seeds, shared_runs: bool = False) -> Paired:
    """``a - b`` over cells of the same pairs (aligned arrays), averaged per seed, with its t
    interval over seeds and a sign-flip p-value; ``shared_runs``: cyclic cross-seed units, the
    interval widened for their sharing and no p-value (NaN)."""
    a, b, seeds = np.asarray(a, float), np.asarray(b, float), np.asarray(seeds)
    if not a.shape == b.shape == seeds.shape or a.ndim != 1 or len(a) == 0:
        raise ValueError(f"need aligned cells, got shapes {a.shape}, {b.shape} and {seeds.shape} seeds")
    per_seed = np.array([(a - b)[seeds == s].mean() for s in np.unique(seeds)])
    diff, lo, hi = t_interval(per_seed, shared_runs=shared_runs)
    return Paired(
        diff,
        lo,
        hi,
        float("nan") if shared_runs else sign_flip_p(per_seed),
        len(per_seed),
        int((per_seed > 0).sum()),
        int((per_seed < 0).sum()),
    )


def newcombe(a, b, episodes: int) -> tuple[np.ndarray, np.ndarray]:
    """95% interval of ``a - b``, two success rates each over ``episodes`` episodes (Newcombe's
    hybrid score interval from Wilson's: it keeps its coverage near 0 and 1, where the Wald
    interval does not). For rates measured on the same episodes it is conservative."""
    z = stats.norm.ppf(0.5 + CONFIDENCE / 2)
    a, b = np.asarray(a, float), np.asarray(b, float)

    def wilson(p):
        centre, n = (p + z * z / (2 * episodes)) / (1 + z * z / episodes), episodes
        half = z * np.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
        return centre - half, centre + half

    (a_lo, a_hi), (b_lo, b_hi) = wilson(a), wilson(b)
    return a - b - np.hypot(a - a_lo, b_hi - b), a - b + np.hypot(a_hi - a, b - b_lo)


def iqm(values: np.ndarray) -> float:
    """Interquartile mean: the mean of the middle 50% (robust to a few outlier cells)."""
    return float(stats.trim_mean(np.asarray(values, float), 0.25))


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


def estimate(values, seeds, *, seed: int = 0, shared_runs: bool = False, rate: bool = False) -> Estimate:
    """Mean of ``values`` (one per cell) with the t interval over per-seed means, and the IQM
    (its seed-bootstrap interval from ``BOOTSTRAP_MIN_SEEDS`` seeds); ``seeds`` names the training
    seed of each cell; ``shared_runs``: cyclic cross-seed units, ``rate``: success rates, the
    interval on the logit scale (:func:`t_interval`)."""
    values, seeds = np.asarray(values, float), np.asarray(seeds)
    if values.shape != seeds.shape or values.ndim != 1 or len(values) == 0:
        raise ValueError(f"need one seed per value, got {values.shape} values and {seeds.shape} seeds")
    by_seed = [values[seeds == s] for s in np.unique(seeds)]
    out: dict[str, float] = {}
    # the mean of the per-seed means (the cell mean when every seed has as many cells)
    seed_means = [part.mean() for part in by_seed]
    out["mean"], out["mean_lo"], out["mean_hi"] = t_interval(seed_means, shared_runs=shared_runs, rate=rate)
    out["iqm"] = iqm(values)
    out["iqm_lo"] = out["iqm_hi"] = float("nan")
    if len(by_seed) >= BOOTSTRAP_MIN_SEEDS:
        out["iqm_lo"] = out["iqm_hi"] = out["iqm"]  # every cell equal: the interval is the point
        if np.ptp(values) > 0:
            drawn = stats.bootstrap(
                (np.arange(len(by_seed)),),
                lambda idx: iqm(np.concatenate([by_seed[i] for i in idx])),
                vectorized=False,
                n_resamples=RESAMPLES,
                confidence_level=CONFIDENCE,
                method="percentile",
                rng=np.random.default_rng(seed),
            )
            out["iqm_lo"], out["iqm_hi"] = map(float, drawn.confidence_interval)
    return Estimate(**out, cells=len(values), seeds=len(by_seed))


def estimates(
    table: pd.DataFrame, value: str, by: str = "method", seed_col: str = "seed", rate: bool = False
) -> pd.DataFrame:
    """One :class:`Estimate` row per ``by`` group of a cell table (``rate``: see :func:`estimate`)."""
    rows = [
        {by: key, **asdict(estimate(part[value].to_numpy(), part[seed_col].to_numpy(), rate=rate))}
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
