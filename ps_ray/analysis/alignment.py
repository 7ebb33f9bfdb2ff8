"""Alignment scores that a collapsed interface cannot game (docs/alignment.md).

The paper's distances (mean 1 - cos, mean L2 between two networks' interfaces on the same probe
states) go to zero when every interface collapses to one direction. Beside them:

- **retrieval** across networks (relreps' measure): for each probe state i, rank network B's
  vector of state i among B's vectors of all probes by cosine similarity to network A's vector of
  state i. Mean reciprocal rank (MRR) and top-1, averaged over both directions. 1.0 means every
  state is recognised in the other network; chance is about ln(N)/N (MRR) and 1/N (top-1).
  A constant interface ties every candidate and scores chance.
- **spread** within one network: sqrt(total variance across probes) / RMS norm, in [0, 1].
  0 for a constant interface, 1 for a zero-mean one; below :data:`COLLAPSE_SPREAD` is flagged.
"""

from __future__ import annotations

import numpy as np

COLLAPSE_SPREAD = 0.05


def _unit(x: np.ndarray) -> np.ndarray:
    x = np.asarray(x, np.float64)
    return x / np.maximum(np.linalg.norm(x, axis=-1, keepdims=True), 1e-12)


def _ranks(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Rank (1 = best) of b_i among all b_j by cosine to a_i; ties count against the match
    (a candidate as similar as the true one ranks ahead of it), so ties cannot score."""
    sim = _unit(a) @ _unit(b).T
    true = np.diag(sim)[:, None]
    return (sim >= true - 1e-12).sum(1)


def retrieval(a: np.ndarray, b: np.ndarray) -> dict[str, float]:
    """MRR and top-1 of matching probe states across two interfaces (N x K each), symmetrised."""
    a, b = np.asarray(a), np.asarray(b)
    if a.shape[0] != b.shape[0] or a.ndim != 2 or b.ndim != 2:
        raise ValueError(
            f"interfaces must be (N, K) arrays over the same N probes, got {a.shape} and {b.shape}"
        )
    ranks = np.concatenate([_ranks(a, b), _ranks(b, a)])
    return {"mrr": float(np.mean(1.0 / ranks)), "top1": float(np.mean(ranks == 1))}


def chance_mrr(n: int) -> float:
    """Expected MRR of a random ranking of n candidates: H_n / n."""
    return float(np.sum(1.0 / np.arange(1, n + 1)) / n)


def spread(x: np.ndarray) -> float:
    """sqrt(sum of per-dimension variances) / RMS vector norm: 0 constant, 1 zero-mean."""
    x = np.asarray(x, np.float64)
    rms = np.sqrt(np.mean(np.sum(x**2, axis=1)))
    return float(np.sqrt(np.sum(x.var(0))) / rms) if rms > 0 else 0.0


def collapsed(x: np.ndarray, threshold: float = COLLAPSE_SPREAD) -> bool:
    return spread(x) < threshold
