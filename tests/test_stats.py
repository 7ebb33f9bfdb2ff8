"""Statistics at the seed counts of RL studies: t intervals over per-seed means, paired
differences with a sign-flip p-value, and their coverage by simulation (docs/statistics.md)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats as sp

from ps_ray.analysis import stats


def _cells(seeds: int, pairs: int = 6, seed: int = 0):
    g = np.random.default_rng(seed)
    seed_effect = g.normal(0, 0.1, seeds)
    values = np.clip(0.4 + seed_effect[:, None] + g.normal(0, 0.1, (seeds, pairs)), 0, 1)
    return values.ravel(), np.repeat(np.arange(seeds), pairs)


def test_interval_covers_the_mean_and_narrows_with_more_seeds():
    widths = []
    for n in (3, 10, 40):
        values, seeds = _cells(n)
        e = stats.estimate(values, seeds)
        assert e.mean == pytest.approx(values.mean())
        assert e.mean_lo <= e.mean <= e.mean_hi
        assert (e.cells, e.seeds) == (len(values), n)
        widths.append(e.mean_hi - e.mean_lo)
    assert widths[0] > widths[1] > widths[2]


def test_the_interval_is_the_t_interval_of_the_seed_means():
    """Cells of one seed move together: the interval is that of 4 seed means, not of 40 cells."""
    values = np.repeat([0.1, 0.5, 0.9, 0.3], 10)
    e = stats.estimate(values, np.repeat(np.arange(4), 10))
    half = sp.t.ppf(0.975, 3) * np.std([0.1, 0.5, 0.9, 0.3], ddof=1) / 2
    assert (e.mean_lo, e.mean_hi) == pytest.approx((0.45 - half, 0.45 + half))
    assert stats.iqm(np.array([0, 0.5, 0.5, 0.5, 0.5, 0.5, 0.5, 1.0])) == pytest.approx(0.5)


def test_iqm_has_an_interval_only_from_ten_seeds():
    few, many = _cells(5), _cells(12)
    assert np.isnan(stats.estimate(*few).iqm_lo)
    e = stats.estimate(*many)
    assert e.iqm_lo <= e.iqm <= e.iqm_hi


def test_one_seed_has_no_interval():
    e = stats.estimate([0.2, 0.4, 0.6], [101, 101, 101])
    assert np.isnan(e.mean_lo) and e.text() == "0.40 [n/a]"
    assert stats.paired([0.5], [0.2], [1]).text() == "+0.30 [n/a: 1 seed]"
    with pytest.raises(ValueError, match="one seed per value"):
        stats.estimate([0.1, 0.2], [1])


def test_paired_differences_are_per_seed_and_count_wins():
    seeds = np.repeat([1, 2, 3, 4, 5, 6], 4)
    b = np.random.default_rng(0).uniform(0, 1, len(seeds))
    shift = np.repeat([0.1, 0.2, 0.1, 0.3, 0.2, 0.1], 4)
    result = stats.paired(b + shift, b, seeds)
    assert result.diff == pytest.approx(shift.mean())
    assert (result.wins, result.losses, result.seeds) == (6, 0, 6)
    assert result.p == pytest.approx(2 / 64)  # all six up: the exact test's floor
    assert result.lo > 0
    flat = stats.paired(b, b, seeds)
    assert (flat.diff, flat.p, flat.wins) == (0.0, 1.0, 0)


def test_sign_flip_p_cannot_reach_five_percent_at_five_seeds():
    assert stats.sign_flip_p([0.3, 0.2, 0.4, 0.1, 0.25]) == pytest.approx(2 / 32)
    assert stats.sign_flip_p([0.3, -0.2, 0.4, 0.1, 0.25]) > 0.1
    # so five seeds are said as seeds up, never as the test's floor "p 0.062"; six get their p
    five = stats.paired([0.9, 0.8, 0.7, 0.9, 0.8], [0.5] * 5, [1, 2, 3, 4, 5])
    assert five.text() == "+0.32 [+0.22, +0.42], 5/5 seeds up"
    six = stats.paired([0.9, 0.8, 0.7, 0.9, 0.8, 0.8], [0.5] * 6, [1, 2, 3, 4, 5, 6])
    assert six.text().endswith("p 0.031, 6/6 seeds up")


@pytest.mark.parametrize("n", [3, 5, 8])
def test_a_rate_s_interval_stays_in_0_1_and_keeps_its_coverage_near_1(n):
    """Seed means of success near 0.9 (a seed effect, then 60 episodes): the interval on the logit
    scale never leaves [0, 1] and covers the true rate about 95% of the time at 3-8 seeds; the
    plain t interval passes 1 in a share of studies."""
    g = np.random.default_rng(n)
    true, covered, past_one = 0.9, 0, 0
    for _ in range(2000):
        values = g.binomial(60, g.beta(18, 2, size=n)) / 60
        _, lo, hi = stats.t_interval(values, rate=True)
        assert 0 <= lo <= hi <= 1  # [1, 1] only where every seed scored 1
        covered += lo <= true <= hi
        past_one += stats.t_interval(values)[2] > 1
    assert 0.93 <= covered / 2000 <= 0.98
    assert past_one > 0
    assert stats.t_interval([1.0, 1.0, 1.0], rate=True) == (1.0, 1.0, 1.0)  # all at 1: no width


@pytest.mark.parametrize("n", [3, 5])
def test_the_t_interval_keeps_its_coverage_at_small_n_and_the_seed_bootstrap_does_not(n):
    """4,000 simulated studies of n seeds (6 cells each, a seed effect and cell noise): the t
    interval over seed means covers the true mean about 95% of the time; a percentile bootstrap
    over seeds (what the tables used before) covers about 75% at n = 3."""
    g = np.random.default_rng(n)
    studies, pairs, true = 4000, 6, 0.4
    cells = true + g.normal(0, 0.1, (studies, n, 1)) + g.normal(0, 0.1, (studies, n, pairs))
    means = cells.mean(axis=2)
    half = sp.t.ppf(0.975, n - 1) * means.std(axis=1, ddof=1) / np.sqrt(n)
    t_cover = np.mean(np.abs(means.mean(axis=1) - true) <= half)
    assert 0.935 <= t_cover <= 0.965
    # the interval the code gives is that one (one study checked against the formula)
    e = stats.estimate(cells[0].ravel(), np.repeat(np.arange(n), pairs))
    assert e.mean_hi - e.mean == pytest.approx(half[0])
    # percentile bootstrap over seeds, vectorised: resample seed means with replacement
    draws = g.integers(0, n, (studies, 500, n))
    boot = np.take_along_axis(means[:, None, :].repeat(500, 1), draws, axis=2).mean(axis=2)
    lo, hi = np.percentile(boot, [2.5, 97.5], axis=1)
    boot_cover = np.mean((lo <= true) & (true <= hi))
    assert boot_cover < t_cover - 0.05
    if n == 3:
        assert boot_cover < 0.85


def test_ratio_of_paired_means_keeps_each_seeds_pair_together():
    base = np.array([3100.0, 4100.0, 6100.0, 4100.0, 5100.0, 3100.0])
    point, lo, hi = stats.ratio_of_means(1.5 * base, base)
    assert point == lo == hi == pytest.approx(1.5)  # every resample of paired seeds gives 1.5
    shuffled = np.roll(1.5 * base, 1)  # the same values, paired with other seeds
    point, lo, hi = stats.ratio_of_means(shuffled, base)
    assert point == pytest.approx(1.5) and lo < 1.5 < hi
    assert np.isnan(stats.ratio_of_means([2.0], [1.0])[1])
    with pytest.raises(ValueError, match="paired"):
        stats.ratio_of_means([1.0, 2.0], [1.0])


@pytest.mark.parametrize("n", [3, 5, 8])
def test_cross_seed_units_that_share_runs_keep_their_coverage_only_when_widened(n):
    """Unit i joins run i's task half with run i+1's robot half (cyclically). In the worst case
    the sharing allows (the two halves of a run equally important and perfectly correlated) the
    plain t interval over units covers about 0.82; widened for the sharing it keeps 0.95."""
    g = np.random.default_rng(n)
    studies = 3000
    task = g.normal(size=(studies, n))
    units = task + np.roll(task, -1, axis=1) + 0.3 * g.normal(size=(studies, n))  # robot half = task half
    plain = [stats.t_interval(u) for u in units]
    shared = [stats.t_interval(u, shared_runs=True) for u in units]
    covered = lambda found: np.mean([lo <= 0 <= hi for _, lo, hi in found])  # noqa: E731
    assert covered(plain) < 0.88
    assert covered(shared) >= 0.93
    # the widened interval is never narrower than the plain one
    assert all(wide[2] - wide[1] >= narrow[2] - narrow[1] for wide, narrow in zip(shared, plain))
    d = stats.paired(units[0], np.zeros(n), np.arange(n), shared_runs=True)
    assert np.isnan(d.p) and "p " not in d.text() and f"/{n} seeds up" in d.text()


def test_two_units_that_share_both_runs_have_no_interval():
    assert np.isnan(stats.t_interval([0.1, 0.3], shared_runs=True)[1])


def test_the_episodes_interval_of_a_difference_is_newcombes_and_keeps_its_coverage():
    """Newcombe's (1998) worked example: 9/10 against 3/10, 0.6 [0.1705, 0.8090]. Over 4,000
    simulated pairs of 200 episodes each, at the low success rates of the push study, it covers
    the true difference at least 95% of the time."""
    lo, hi = stats.newcombe(0.9, 0.3, 10)
    assert (lo, hi) == (pytest.approx(0.1705, abs=1e-4), pytest.approx(0.8090, abs=1e-4))
    g = np.random.default_rng(0)
    for a, b in ((0.3, 0.45), (0.1, 0.1), (0.05, 0.2)):
        rates = g.binomial(200, [a, b], (4000, 2)) / 200
        lo, hi = stats.newcombe(rates[:, 0], rates[:, 1], 200)
        assert np.mean((lo <= a - b) & (a - b <= hi)) >= 0.94
