"""Anchor selection for the relative-representation interface of Policy Stitching.

What the authors do (docs/authors_code.md §4, ``permutation_measure`` and
``generate_anchors_with_kmeans.py``):

1. Roll out a trained policy and record the task module's input
   (``concatenate([task_state, desired_goal])``) at time steps 5-9 of every episode, where
   step ``t`` is the observation the policy sees before its ``t``-th action (``t = 0`` is the
   reset observation).
2. Pool the states of the source task variants and run
   ``KMeans(n_clusters=k, random_state=0)`` (k-means++, ``n_init=10`` in sklearn 1.1.3).
3. For every centroid take the nearest *real* state (Euclidean,
   ``pairwise_distances_argmin_min``). The authors keep duplicates.

Here:

- :func:`ps_ray.data.collect.collect_task_states` is step 1 (every episode is reset with its
  own seed).
- :func:`select_anchor_indices` / :func:`select_anchors` are steps 2-3. ``n_init`` defaults to
  10 explicitly (sklearn >= 1.4 defaults to ``"auto"``, i.e. 1 run for k-means++).
  ``distinct=True`` (the default) makes the anchors pairwise distinct rows: when two
  centroids share the same nearest state, the centroid closest to it keeps it and the other
  takes its nearest state not taken yet. Duplicate anchors would only give the relative
  representation identical (wasted) coordinates. When no collision happens - the usual
  case - the result is bit-identical to the authors' rule; ``distinct=False`` reproduces it
  always, duplicates included.
- :class:`AnchorSet` bundles the anchors with a content hash (:func:`anchor_hash`) and a
  provenance dict; :mod:`ps_ray.data.anchor_file` stores it as an ``.npz`` that never needs pickle
  and makes one from any file of task states.

No torch and no Ray here: numpy, scikit-learn and gymnasium-style env objects only.
"""

from __future__ import annotations

import hashlib
import json
import logging
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ps_ray.errors import UserError

__all__ = [
    "AnchorSet",
    "anchor_hash",
    "make_anchor_set",
    "select_anchor_indices",
    "select_anchors",
]

log = logging.getLogger(__name__)

_HASH_DOMAIN = b"ps_ray.anchors.v1\x00"  # a format constant: never renamed with the module

# --------------------------------------------------------------------------- selection


def _as_states(states: Any, name: str = "states") -> np.ndarray:
    arr = np.asarray(states)
    if arr.dtype.kind not in "biuf":
        raise UserError(f"{name} must be a numeric array, got dtype {arr.dtype}")
    if arr.ndim != 2 or arr.shape[0] == 0 or arr.shape[1] == 0:
        raise UserError(f"{name} must be a non-empty (N, dim) matrix, got shape {arr.shape}")
    arr = np.ascontiguousarray(arr, dtype=np.float32)
    if not np.all(np.isfinite(arr)):
        raise UserError(f"{name} contains NaN or infinite values (after casting to float32)")
    return arr


def distinct_nearest_rows(
    centers: np.ndarray, states: np.ndarray, idx: np.ndarray, dist: np.ndarray
) -> np.ndarray:
    """Reassign centroids whose nearest state is already taken (by value) by a closer centroid.

    Centroids are served in order of their distance to their nearest state; a centroid whose
    nearest state (as a value; equal rows count as one) is taken gets its nearest free one.
    Requires at least ``len(centers)`` distinct rows in ``states``.
    """
    uniq, first, value_id = np.unique(states, axis=0, return_index=True, return_inverse=True)
    value_id = value_id.reshape(-1)
    chosen = value_id[idx]
    if len(np.unique(chosen)) == len(idx):
        return idx
    out = idx.copy()
    taken: set[int] = set()
    losers: list[int] = []
    for c in np.argsort(dist, kind="stable"):
        if int(chosen[c]) in taken:
            losers.append(int(c))
        else:
            taken.add(int(chosen[c]))
    from sklearn.metrics import pairwise_distances

    d = pairwise_distances(centers[losers], uniq)  # (losers, distinct states)
    for row, c in enumerate(losers):
        for v in np.argsort(d[row], kind="stable"):
            if int(v) not in taken:
                taken.add(int(v))
                out[c] = first[v]
                break
    return out


def select_anchor_indices(
    states: np.ndarray, k: int, *, seed: int = 0, n_init: int = 10, distinct: bool = True
) -> np.ndarray:
    """Row indices into ``states`` (cast to float32) of the ``k`` anchors, in centroid order.

    k-means (``KMeans(n_clusters=k, random_state=seed, n_init=n_init)``, k-means++, on one
    thread so the result does not depend on the machine's cores), then the nearest real state to
    each centroid; see the module docstring for ``distinct``.
    """
    from sklearn.cluster import KMeans
    from sklearn.metrics import pairwise_distances_argmin_min
    from threadpoolctl import threadpool_limits

    x = _as_states(states)
    if int(k) != k or k < 1:
        raise UserError(f"k must be a positive integer, got {k!r}")
    k = int(k)
    n_distinct = len(np.unique(x, axis=0))
    if n_distinct < k:
        raise UserError(
            f"cannot select {k} anchors from {x.shape[0]} states with only {n_distinct} "
            f"distinct rows; collect more states or lower k"
        )
    # One thread: sklearn's k-means splits its sums by OpenMP thread, so its result depends on
    # the thread count (measured: anchors 0.03 apart with 1 and 2 threads on reach's states).
    # Pinned, the anchors of a seed are the same on a laptop, a cluster node and in any process.
    with threadpool_limits(limits=1):
        kmeans = KMeans(n_clusters=k, random_state=seed, n_init=n_init).fit(x)
    centers = kmeans.cluster_centers_.astype(np.float32, copy=False)
    idx, dist = pairwise_distances_argmin_min(centers, x)
    idx = np.asarray(idx, dtype=np.int64)
    if distinct:
        idx = distinct_nearest_rows(centers, x, idx, np.asarray(dist))
    return idx


def select_anchors(
    states: np.ndarray, k: int, *, seed: int = 0, n_init: int = 10, distinct: bool = True
) -> np.ndarray:
    """``(k, dim)`` float32 anchors: actual rows of ``states`` nearest to the k-means centroids.

    Raises ``ValueError`` when ``states`` has fewer than ``k`` distinct rows.
    """
    x = _as_states(states)
    idx = select_anchor_indices(x, k, seed=seed, n_init=n_init, distinct=distinct)
    return np.ascontiguousarray(x[idx])


# --------------------------------------------------------------------------- hashing


def _canonical(anchors: Any) -> np.ndarray:
    arr = np.asarray(anchors)
    if arr.dtype.kind not in "biuf":
        raise UserError(f"anchors must be numeric, got dtype {arr.dtype}")
    arr = np.ascontiguousarray(arr, dtype="<f4")
    if not np.all(np.isfinite(arr)):
        raise UserError("anchors contain NaN or infinite values")
    return arr + np.float32(0.0)  # -0.0 -> +0.0: equal values hash equally


def anchor_hash(anchors: np.ndarray) -> str:
    """sha256 hex digest of the anchors as little-endian float32 in C order, shape included.

    The input is cast to float32 first; ``-0.0`` and ``0.0`` hash the same. Stable across
    runs, processes and platforms.
    """
    arr = _canonical(anchors)
    h = hashlib.sha256(_HASH_DOMAIN)
    h.update(json.dumps({"dtype": "<f4", "shape": list(arr.shape)}, sort_keys=True).encode())
    h.update(arr.tobytes(order="C"))
    return h.hexdigest()


# --------------------------------------------------------------------------- anchor sets


@dataclass(frozen=True, eq=False)
class AnchorSet:
    """Anchors (read-only ``(k, dim)`` float32), their :func:`anchor_hash` and a provenance dict.

    The constructor checks that ``hash`` matches the anchors; use :meth:`of` to compute it.
    ``provenance`` must be JSON-serialisable and is stored in its JSON round-tripped form
    (tuples become lists), so a saved and loaded set compares equal to the original.
    """

    anchors: np.ndarray
    hash: str
    provenance: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        arr = np.asarray(self.anchors)
        if arr.ndim != 2 or arr.shape[0] < 1 or arr.shape[1] < 1:
            raise UserError(f"anchors must be a non-empty (k, dim) matrix, got shape {arr.shape}")
        arr = np.array(_canonical(arr), dtype=np.float32, order="C", copy=True)
        arr.setflags(write=False)
        expected = anchor_hash(arr)
        if self.hash != expected:
            raise UserError(f"anchor hash {self.hash!r} does not match the anchors ({expected})")
        try:
            prov = json.loads(json.dumps(dict(self.provenance), sort_keys=True, allow_nan=False))
        except (TypeError, ValueError) as exc:
            raise UserError(f"provenance must be JSON-serialisable: {exc}") from None
        object.__setattr__(self, "anchors", arr)
        object.__setattr__(self, "provenance", prov)

    @classmethod
    def of(cls, anchors: np.ndarray, provenance: Mapping[str, Any] | None = None) -> AnchorSet:
        return cls(np.asarray(anchors), anchor_hash(anchors), dict(provenance or {}))

    @property
    def k(self) -> int:
        return int(self.anchors.shape[0])

    @property
    def dim(self) -> int:
        return int(self.anchors.shape[1])

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, AnchorSet):
            return NotImplemented
        return (
            self.hash == other.hash
            and self.provenance == other.provenance
            and np.array_equal(self.anchors, other.anchors)
        )

    def __hash__(self) -> int:
        return hash(self.hash)


def selection_provenance(
    states: np.ndarray, k: int, seed: int, n_init: int, distinct: bool, **source: Any
) -> dict[str, Any]:
    """What an anchor set records about its selection: ``source`` names where the states came
    from; then their count and width, the k-means settings and the library versions."""
    return {
        "method": "kmeans_nearest_real_state",
        **source,
        "num_states": int(states.shape[0]),
        "dim": int(states.shape[1]),
        "k": int(k),
        "seed": int(seed),
        "n_init": int(n_init),
        "distinct": bool(distinct),
        "versions": _library_versions(),
    }


def _library_versions() -> dict[str, str]:
    import sklearn

    return {"numpy": np.__version__, "sklearn": sklearn.__version__}


def make_anchor_set(
    states_by_source: Mapping[str, np.ndarray],
    k: int,
    *,
    seed: int = 0,
    n_init: int = 10,
    distinct: bool = True,
    extra_provenance: Mapping[str, Any] | None = None,
) -> AnchorSet:
    """Pool the task states of several sources (in the given order) and select ``k`` anchors.

    The provenance records the sources with their state counts, the selection settings and
    the numpy / scikit-learn versions; ``extra_provenance`` (e.g. the collection ``steps``,
    episodes, policy checkpoints) is merged in.
    """
    if not states_by_source:
        raise UserError("no task-state sources given")
    parts = [_as_states(v, name=f"states of source {name!r}") for name, v in states_by_source.items()]
    dims = {p.shape[1] for p in parts}
    if len(dims) != 1:
        shapes = {name: p.shape for name, p in zip(states_by_source, parts)}
        raise UserError(f"task-state sources have different dimensions: {shapes}")
    pooled = np.concatenate(parts)
    anchors = select_anchors(pooled, k, seed=seed, n_init=n_init, distinct=distinct)
    sources = {name: int(p.shape[0]) for name, p in zip(states_by_source, parts)}
    provenance = selection_provenance(pooled, k, seed, n_init, distinct, sources=sources)
    provenance.update(dict(extra_provenance or {}))
    return AnchorSet.of(anchors, provenance)
