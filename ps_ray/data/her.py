"""Hindsight experience replay: a numpy ring buffer of whole episodes with 'future' relabelling.

Follows the authors' HER (docs/authors_code.md §5, from TianhongDai/hindsight-experience-replay):
episode ~ U(stored), t ~ U{0..T-1}; with probability ``relabel_prob`` (replay_k = 4 -> 0.8) the
goal becomes ``achieved_goal[ep, t']`` with t' ~ U{t+1..T}; the reward is recomputed as
``reward_fn(achieved_goal[ep, t+1], goal)``. With a :class:`MarkerShift` (a task said in a
marker's frame) the goal stays real and the named marker moves instead
(:mod:`ps_ray.data.marker_shift`); the rewards are the same. A sample is one vectorised gather per
observation key (no Python object per transition), which is what makes it ~100x cheaper than
RLlib's episode replay (measured: 25-31 ms per RLlib sample against ~2 ms here; README "Design notes").

Pure numpy: no torch, no Ray. Checkpoints are plain ``.npz`` files read with
``allow_pickle=False``.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from ps_ray.data.marker_shift import MarkerShift
from ps_ray.errors import UserError
from ps_ray.store.atomic import atomic_file
from ps_ray.store.formats import HINDSIGHT_REPLAY
from ps_ray.store.npz import NpzError, read_npz

__all__ = ["HindsightReplay", "MarkerShift", "ObsSpec", "RewardFn"]

ObsSpec = Mapping[str, tuple[tuple[int, ...], Any]]  # key -> (per-step shape, dtype-like)
RewardFn = Callable[[np.ndarray, np.ndarray], np.ndarray]  # (achieved (N,G), goal (N,G)) -> (N,)

_FORMAT = HINDSIGHT_REPLAY.id


class HindsightReplay:
    """Ring buffer of fixed-length episodes (horizon T) with vectorised 'future' relabelling.

    Storage is allocated up front with ``np.zeros`` (pages are committed by the OS only when
    written): per key ``(capacity, T+1, *shape)`` in the spec dtype, actions
    ``(capacity, T, A)`` float32. Once full, new episodes overwrite the oldest (FIFO).
    """

    def __init__(
        self,
        obs_spec: ObsSpec,
        action_dim: int,
        horizon: int,
        capacity_episodes: int,
        reward_fn: RewardFn,
        relabel_prob: float = 0.8,
        seed: int | None = None,
        achieved_key: str = "achieved_goal",
        goal_key: str = "desired_goal",
        marker: MarkerShift | None = None,
    ) -> None:
        self._spec: dict[str, tuple[tuple[int, ...], np.dtype]] = {
            str(k): (tuple(int(d) for d in shape), np.dtype(dt)) for k, (shape, dt) in obs_spec.items()
        }
        if not self._spec:
            raise ValueError("obs_spec is empty")
        for key in (achieved_key, goal_key):
            if key not in self._spec:
                raise ValueError(f"{key!r} is not in obs_spec (keys: {sorted(self._spec)})")
        if self._spec[achieved_key][0] != self._spec[goal_key][0]:
            raise ValueError(
                f"{achieved_key!r} shape {self._spec[achieved_key][0]} != {goal_key!r} shape "
                f"{self._spec[goal_key][0]}"
            )
        if min(action_dim, horizon, capacity_episodes) < 1:
            raise ValueError("action_dim, horizon and capacity_episodes must be >= 1")
        if not 0.0 <= relabel_prob <= 1.0:
            raise ValueError(f"relabel_prob must be in [0, 1], got {relabel_prob}")
        self.action_dim = int(action_dim)
        self.horizon = int(horizon)
        self._capacity = int(capacity_episodes)
        self.reward_fn = reward_fn
        self.relabel_prob = float(relabel_prob)
        self.achieved_key = achieved_key
        self.goal_key = goal_key
        if marker is not None and marker.key not in self._spec:
            raise ValueError(f"{marker.key!r} is not in obs_spec (keys: {sorted(self._spec)})")
        self.marker = marker
        self._rng = np.random.Generator(np.random.PCG64(seed))
        self._episodes_added = 0
        T1, cap = self.horizon + 1, self._capacity
        self._obs = {k: np.zeros((cap, T1, *s), dt) for k, (s, dt) in self._spec.items()}
        self._actions = np.zeros((cap, self.horizon, self.action_dim), np.float32)
        # Flat (episode*step)-major views: one np.take per key and sample.
        self._obs_flat = {k: a.reshape(cap * T1, *a.shape[2:]) for k, a in self._obs.items()}
        self._act_flat = self._actions.reshape(cap * self.horizon, self.action_dim)

    # ------------------------------------------------------------------ sizes
    @property
    def obs_spec(self) -> dict[str, tuple[tuple[int, ...], np.dtype]]:
        return dict(self._spec)

    @property
    def capacity_episodes(self) -> int:
        return self._capacity

    @property
    def episodes_added(self) -> int:
        """Lifetime number of episodes added (the ring pointer is this modulo capacity)."""
        return self._episodes_added

    @property
    def num_episodes(self) -> int:
        return min(self._episodes_added, self._capacity)

    @property
    def num_transitions(self) -> int:
        return self.num_episodes * self.horizon

    @property
    def nbytes(self) -> int:
        """Bytes allocated for storage (all slots, filled or not)."""
        return sum(a.nbytes for a in self._obs.values()) + self._actions.nbytes

    def __len__(self) -> int:
        return self.num_transitions

    # ------------------------------------------------------------------ write
    def add_episodes(self, obs: Mapping[str, np.ndarray], actions: np.ndarray) -> None:
        """Write N whole episodes: obs[k] (N, T+1, *shape), actions (N, T, A); oldest overwritten."""
        if set(obs) != set(self._spec):
            raise ValueError(f"obs keys {sorted(obs)} != obs_spec keys {sorted(self._spec)}")
        actions = np.asarray(actions)
        n = actions.shape[0] if actions.ndim == 3 else -1
        if actions.shape != (n, self.horizon, self.action_dim):
            raise ValueError(f"actions shape {actions.shape} != (N, {self.horizon}, {self.action_dim})")
        arrays = {k: np.asarray(v) for k, v in obs.items()}
        for k, a in arrays.items():
            if a.shape != (n, self.horizon + 1, *self._spec[k][0]):
                want = (n, self.horizon + 1, *self._spec[k][0])
                raise ValueError(f"obs[{k!r}] shape {a.shape} != {want} (N, T+1, *shape)")
        if n == 0:
            return
        skip = max(0, n - self._capacity)  # more episodes than slots: only the newest survive
        start = (self._episodes_added + skip) % self._capacity
        count = n - skip
        first = min(count, self._capacity - start)  # at most two contiguous slices (wrap)
        for dst, src in [*((self._obs[k], a) for k, a in arrays.items()), (self._actions, actions)]:
            dst[start : start + first] = src[skip : skip + first]
            dst[: count - first] = src[skip + first :]
        self._episodes_added += n

    # ------------------------------------------------------------------ read
    def sample(self, batch_size: int) -> dict[str, np.ndarray]:
        """One vectorised HER gather of ``batch_size`` transitions (see module docstring).

        Returns "obs/<key>" and "next_obs/<key>" (B, *shape) for every key, with the goal key in
        both replaced by the (possibly relabelled) goal; "actions" (B, A) float32; "rewards" (B,)
        float32. All arrays are C-contiguous.
        """
        size = self.num_episodes
        if size == 0:
            raise RuntimeError("cannot sample from an empty HindsightReplay")
        if batch_size < 1:
            raise ValueError(f"batch_size must be >= 1, got {batch_size}")
        B, T, rng = int(batch_size), self.horizon, self._rng
        ep = rng.integers(0, size, B)
        t = rng.integers(0, T, B)
        relabel = rng.random(B) < self.relabel_prob
        t_future = rng.integers(t + 1, T + 1)  # U{t+1..T}, drawn for every row: fixed RNG use

        row = ep * (T + 1) + t
        both = np.concatenate([row, row + 1])  # obs rows then next_obs rows: one take per key
        out: dict[str, np.ndarray] = {}
        for k, flat in self._obs_flat.items():
            if k == self.goal_key:
                continue
            g = flat.take(both, axis=0)
            out[f"obs/{k}"], out[f"next_obs/{k}"] = g[:B], g[B:]
        goals = self._obs_flat[self.goal_key].take(row, axis=0)
        if relabel.any():
            future_rows = ep[relabel] * (T + 1) + t_future[relabel]
            future = self._obs_flat[self.achieved_key].take(future_rows, axis=0)
            if self.marker is None:
                goals[relabel] = future
            else:
                shift = future - goals[relabel]
                for side in ("obs", "next_obs"):
                    self.marker.move(out, side, relabel, shift, self.achieved_key)
        out[f"obs/{self.goal_key}"], out[f"next_obs/{self.goal_key}"] = goals, goals.copy()
        out["actions"] = self._act_flat.take(ep * T + t, axis=0)
        rewards = np.asarray(self.reward_fn(out[f"next_obs/{self.achieved_key}"], goals))
        if rewards.size != B:
            raise ValueError(f"reward_fn returned shape {rewards.shape}, expected ({B},)")
        out["rewards"] = np.ascontiguousarray(rewards, dtype=np.float32).reshape(B)
        return out

    def relabelled(self, obs: Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
        """Every step 0..T-1 of N episodes obs[k] (N, T+1, *shape) as training reads it: (N*T, *shape)
        per key, the goal relabelled as :meth:`sample` relabels it (probability ``relabel_prob``,
        an achieved goal t' ~ U{t+1..T} of the same episode), drawn from this buffer's RNG.

        What the input normalisers must be updated from: their statistics then cover the goals the
        learner trains on, as the reference HER code feeds its normaliser relabelled transitions
        (docs/authors_code.md §5). Real goals alone can be far narrower (zero on the marker family).
        """
        arrays = {k: np.asarray(v) for k, v in obs.items()}
        goal, achieved = arrays[self.goal_key], arrays[self.achieved_key]
        n, T, rng = goal.shape[0], goal.shape[1] - 1, self._rng
        t = np.broadcast_to(np.arange(T), (n, T))
        relabel = rng.random((n, T)) < self.relabel_prob
        t_future = rng.integers(t + 1, T + 1)
        future = np.take_along_axis(achieved, t_future[..., None], axis=1)
        out = {k: a[:, :T].reshape(n * T, *a.shape[2:]).copy() for k, a in arrays.items()}
        if self.marker is None:
            goals = np.where(relabel[..., None], future, goal[:, :T])
            out[self.goal_key] = goals.reshape(n * T, *goal.shape[2:]).astype(goal.dtype)
        else:
            rows = relabel.reshape(-1)
            shift = (future - goal[:, :T]).reshape(n * T, -1)[rows]
            self.marker.move({f"obs/{k}": a for k, a in out.items()}, "obs", rows, shift, self.achieved_key)
        return out

    def sample_many(self, n_batches: int, batch_size: int) -> dict[str, np.ndarray]:
        """``n_batches * batch_size`` i.i.d. rows in one gather (K minibatches, batch-major)."""
        return self.sample(int(n_batches) * int(batch_size))

    # ------------------------------------------------------------------ checkpoint
    def _meta(self) -> dict[str, Any]:
        return {
            "format": _FORMAT,
            "obs_spec": {k: [list(s), dt.str] for k, (s, dt) in self._spec.items()},
            "action_dim": self.action_dim,
            "horizon": self.horizon,
            "capacity_episodes": self._capacity,
            "relabel_prob": self.relabel_prob,
            "achieved_key": self.achieved_key,
            "goal_key": self.goal_key,
            "episodes_added": self._episodes_added,
            "rng_state": self._rng.bit_generator.state,
        }

    def save(self, path: str | Path) -> None:
        """Write the filled slots, ring position and RNG state to an uncompressed .npz (no pickle).

        Written to a temporary file and renamed, so an interrupted save never leaves a torn file.
        """
        path = Path(path)
        n = self.num_episodes
        arrays = {f"obs/{k}": a[:n] for k, a in self._obs.items()}  # slots fill from 0 upward
        arrays["actions"] = self._actions[:n]
        arrays["meta"] = np.array(json.dumps(self._meta()))  # 0-d unicode array, not pickled
        with atomic_file(path) as f:  # a file object: np.savez must not append ".npz"
            np.savez(f, **arrays)

    @staticmethod
    def _read(path: str | Path) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
        """Read and validate a checkpoint; any problem -> ValueError naming the file. Never unpickles."""
        path = Path(path)

        def bad(why: str) -> ValueError:
            return UserError(f"{path}: not a valid HindsightReplay checkpoint: {why}")

        try:
            arrays = read_npz(path)  # FileNotFoundError passes through as is
        except NpzError as exc:
            raise bad(str(exc)) from None
        meta_arr = arrays.pop("meta", None)
        if meta_arr is None or meta_arr.shape != () or meta_arr.dtype.kind != "U":
            raise bad("no 'meta' string (not written by HindsightReplay.save)")
        try:
            meta = json.loads(str(meta_arr))
        except json.JSONDecodeError as exc:
            raise bad(f"'meta' is not JSON ({exc})") from exc
        fmt = meta.get("format") if isinstance(meta, dict) else None
        if not HINDSIGHT_REPLAY.reads(fmt):
            raise bad(f"format {fmt!r}; this code reads {', '.join(HINDSIGHT_REPLAY.readable)}")
        try:
            spec = {k: (tuple(s), np.dtype(dt)) for k, (s, dt) in meta["obs_spec"].items()}
            ints = ("capacity_episodes", "horizon", "action_dim", "episodes_added")
            cap, T, A, added = (int(meta[k]) for k in ints)
            ok = min(cap, T, A) >= 1 and added >= 0 and 0.0 <= float(meta["relabel_prob"]) <= 1.0
            ok = ok and isinstance(meta["rng_state"], dict) and isinstance(meta["achieved_key"], str)
            ok = ok and isinstance(meta["goal_key"], str)
        except (KeyError, TypeError, ValueError) as exc:
            raise bad(f"malformed meta ({type(exc).__name__}: {exc})") from exc
        if not ok:
            raise bad("meta values out of range")
        n = min(added, cap)
        expected = {f"obs/{k}": ((n, T + 1, *s), dt) for k, (s, dt) in spec.items()}
        expected["actions"] = ((n, T, A), np.dtype(np.float32))
        if set(arrays) != set(expected):
            raise bad(f"arrays {sorted(arrays)} != expected {sorted(expected)}")
        for k, (shape, dt) in expected.items():
            if arrays[k].shape != shape or arrays[k].dtype != dt:
                raise bad(f"{k!r} is {arrays[k].dtype}{arrays[k].shape}, expected {dt}{shape}")
        return meta, arrays

    def load(self, path: str | Path) -> None:
        """Restore contents, ring position and RNG state saved by :meth:`save` into this buffer.

        The file's obs spec, action_dim, horizon, capacity and goal keys must match this buffer's;
        ``reward_fn`` and ``relabel_prob`` stay as configured here.
        """
        self._restore(path, *self._read(path))

    def _matching_rng(self, path: str | Path, meta: dict[str, Any]) -> np.random.Generator:
        """The RNG that ``meta`` (of :meth:`state`) saved, once its layout matches this buffer's."""
        mine = self._meta()
        for key in ("obs_spec", "action_dim", "horizon", "capacity_episodes", "achieved_key", "goal_key"):
            if meta.get(key) != mine[key]:
                raise UserError(f"{path}: {key} {meta.get(key)!r} does not match this buffer's {mine[key]!r}")
        rng = np.random.Generator(np.random.PCG64())
        try:
            rng.bit_generator.state = meta["rng_state"]
        except (TypeError, ValueError, KeyError) as exc:
            raise UserError(f"{path}: bad rng_state ({exc})") from exc
        return rng

    # ------------------------------------------------------------------ episodes by lifetime index
    # Episode e (the e-th ever added) sits in slot e % capacity and never changes while it is held:
    # what an incremental checkpoint (ps_ray.store.replay) writes once and reuses.
    def state(self) -> dict[str, Any]:
        """Layout, ring position and RNG state: JSON-serialisable, without the episodes."""
        return self._meta()

    def live_range(self) -> tuple[int, int]:
        """Lifetime indices [first, end) of the episodes held."""
        return max(0, self._episodes_added - self._capacity), self._episodes_added

    def episodes(self, first: int, end: int) -> dict[str, np.ndarray]:
        """Episodes ``first`` to ``end - 1`` (lifetime indices, all held), as "obs/<key>" and
        "actions" arrays in the layout of :meth:`save`."""
        lo, hi = self.live_range()
        if not lo <= first <= end <= hi:
            raise ValueError(f"episodes [{first}, {end}) are not all held (held: [{lo}, {hi}))")
        slots = np.arange(first, end) % self._capacity
        return {**{f"obs/{k}": a[slots] for k, a in self._obs.items()}, "actions": self._actions[slots]}

    def restore(
        self, where: str, state: dict[str, Any], parts: list[tuple[int, dict[str, np.ndarray]]]
    ) -> None:
        """Restore from :meth:`state` and ``(first, arrays)`` parts that together hold every
        episode of the saved live range (extra episodes are ignored); ``where`` names the source
        in errors."""
        rng = self._matching_rng(where, state)
        added = int(state["episodes_added"])
        lo, hi = max(0, added - self._capacity), added
        held = np.zeros(hi - lo, bool)
        for first, arrays in parts:
            n = arrays["actions"].shape[0]
            a, b = max(first, lo), min(first + n, hi)
            if a >= b:
                continue
            slots = np.arange(a, b) % self._capacity
            for k, dst in self._obs.items():
                dst[slots] = arrays[f"obs/{k}"][a - first : b - first]
            self._actions[slots] = arrays["actions"][a - first : b - first]
            held[a - lo : b - lo] = True
        if not held.all():
            missing = lo + int(np.argmin(held))
            raise UserError(f"{where}: episode {missing} of the saved buffer is in none of its parts")
        for dst in (*self._obs.values(), self._actions):  # slots filled here beyond the saved ones
            dst[hi - lo : self.num_episodes] = 0
        self._episodes_added = added
        self._rng = rng

    def _restore(self, path: str | Path, meta: dict[str, Any], arrays: dict[str, np.ndarray]) -> None:
        rng = self._matching_rng(path, meta)
        n, stale = arrays["actions"].shape[0], self.num_episodes
        for k, a in self._obs.items():
            a[:n] = arrays[f"obs/{k}"]
            a[n:stale] = 0  # only slots this buffer had filled; untouched pages stay uncommitted
        self._actions[:n] = arrays["actions"]
        self._actions[n:stale] = 0
        self._episodes_added = int(meta["episodes_added"])
        self._rng = rng

    @classmethod
    def from_file(cls, path: str | Path, reward_fn: RewardFn) -> HindsightReplay:
        """Build a buffer with the configuration stored in ``path`` and load it."""
        meta, arrays = cls._read(path)
        buf = cls(
            {k: (tuple(s), dt) for k, (s, dt) in meta["obs_spec"].items()},
            meta["action_dim"],
            meta["horizon"],
            meta["capacity_episodes"],
            reward_fn,
            relabel_prob=meta["relabel_prob"],
            achieved_key=meta["achieved_key"],
            goal_key=meta["goal_key"],
        )
        buf._restore(path, meta, arrays)
        return buf
