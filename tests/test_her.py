"""HindsightReplay: relabelling, ring semantics, checkpoints. Real numpy data that encodes (episode, t)."""

from __future__ import annotations

import pickle
from pathlib import Path

import numpy as np
import pytest

from ps_ray.data.her import HindsightReplay
from tests.her_batches import ID0, SPEC, A, T, batch, make, reward_fn


def decode(s: dict[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """-> episode id, t, relabelled mask, future index t' (meaningful where relabelled)."""
    ep, t = s["obs/robot_state"][:, 0], s["obs/robot_state"][:, 1]
    g = s["obs/desired_goal"]
    relabelled = g[:, 2] == 1.0
    return ep.astype(int), t.astype(int), relabelled, g[:, 1].astype(int)


def assert_consistent(s: dict[str, np.ndarray], n: int) -> None:
    ep, t, rl, tf = decode(s)
    assert all(v.shape[0] == n and v.flags.c_contiguous for v in s.values())
    assert all(v.dtype == np.float32 for v in s.values())
    assert s["actions"].shape == (n, A) and s["rewards"].shape == (n,)
    # obs / next_obs are steps t and t+1 of the same episode, for every key
    for pre in ("obs", "next_obs"):
        k = 1 if pre == "next_obs" else 0
        robot = np.stack([ep, t + k, t + k + 0.25, ep + 0.5], -1)
        np.testing.assert_array_equal(s[f"{pre}/robot_state"], robot)
        np.testing.assert_array_equal(s[f"{pre}/task_state"][:, 1], np.stack([t + k, ep, t + k], -1))
        np.testing.assert_array_equal(s[f"{pre}/achieved_goal"], np.stack([ep, t + k, np.ones(n)], -1))
    np.testing.assert_array_equal(s["actions"], np.stack([ep, t], -1))
    assert ((t >= 0) & (t < T)).all()
    # both goals are the same goal; relabelled goals are this episode's achieved goal at t' in [t+1, T]
    np.testing.assert_array_equal(s["obs/desired_goal"], s["next_obs/desired_goal"])
    g = s["obs/desired_goal"]
    assert (g[rl, 0] == ep[rl]).all()
    assert ((tf[rl] >= t[rl] + 1) & (tf[rl] <= T)).all()
    ones = np.ones((~rl).sum())
    np.testing.assert_array_equal(g[~rl], np.stack([ep[~rl], -ones, 2 * ones], -1))
    # rewards: reward_fn(next achieved, goal) on every row; here 0 exactly when t' == t+1
    np.testing.assert_array_equal(s["rewards"], reward_fn(s["next_obs/achieved_goal"], g))
    np.testing.assert_array_equal(s["rewards"] == 0, rl & (tf == t + 1))


def test_relabelling_is_correct_and_fraction_matches() -> None:
    buf = make()
    buf.add_episodes(*batch(range(ID0, ID0 + 20)))
    s = buf.sample(20_000)
    assert_consistent(s, 20_000)
    _, _, rl, _ = decode(s)
    assert abs(rl.mean() - 0.8) < 0.02  # std 0.003 -> ~7 sigma


@pytest.mark.parametrize("p", [0.0, 1.0, 0.3])
def test_relabel_prob_extremes(p: float) -> None:
    buf = make(p=p)
    buf.add_episodes(*batch(range(ID0, ID0 + 5)))
    s = buf.sample(5_000)
    assert_consistent(s, 5_000)
    frac = decode(s)[2].mean()
    assert frac == p if p in (0.0, 1.0) else abs(frac - p) < 0.03


def test_future_index_covers_t_plus_1_to_T_uniformly() -> None:
    buf = make(p=1.0)
    buf.add_episodes(*batch(range(ID0, ID0 + 3)))
    _, t, _, tf = decode(buf.sample(30_000))
    counts = np.zeros((T, T + 1), int)
    np.add.at(counts, (t, tf), 1)
    for ti in range(T):
        assert counts[ti, : ti + 1].sum() == 0  # never t or earlier
        row = counts[ti, ti + 1 :]  # every t' in t+1..T appears (T included), roughly uniformly
        assert (row > 0).all() and abs(row / row.mean() - 1).max() < 0.25
    assert counts[:, T].sum() > 0 and (counts.sum(1) > 0).all()


def test_relabelled_steps_are_the_goals_training_reads() -> None:
    """What the normalisers see: every step 0..T-1 of the new episodes, each other key as stored,
    the goal a later achieved goal of the same episode with probability relabel_prob."""
    buf = make()
    obs, _ = batch(range(ID0, ID0 + 400))
    steps = buf.relabelled(obs)
    assert {k: v.shape for k, v in steps.items()} == {k: (400 * T, *s) for k, (s, _) in SPEC.items()}
    assert all(v.dtype == np.float32 for v in steps.values())
    for key in ("robot_state", "task_state", "achieved_goal"):
        np.testing.assert_array_equal(steps[key], obs[key][:, :T].reshape(steps[key].shape))
    ep, t = steps["robot_state"][:, 0], steps["robot_state"][:, 1]
    goal = steps["desired_goal"]
    relabelled = goal[:, 2] == 1.0  # an achieved goal (eid, t', 1), else the real one (eid, -1, 2)
    np.testing.assert_array_equal(goal[:, 0], ep)  # always from its own episode
    assert (goal[relabelled, 1] > t[relabelled]).all() and (goal[relabelled, 1] <= T).all()
    assert (goal[~relabelled, 1] == -1).all()
    assert abs(relabelled.mean() - 0.8) < 0.02
    assert len(buf) == 0  # nothing was stored


def test_ring_wraps_overwriting_oldest_and_samples_only_filled_slots() -> None:
    buf = make(capacity=5)
    buf.add_episodes(*batch([ID0, ID0 + 1, ID0 + 2]))
    assert (buf.num_episodes, buf.num_transitions, buf.capacity_episodes) == (3, 3 * T, 5)
    assert set(decode(buf.sample(2_000))[0]) == {ID0, ID0 + 1, ID0 + 2}  # never an empty slot
    buf.add_episodes(*batch(range(ID0 + 3, ID0 + 7)))  # wraps across the end of the ring
    assert buf.num_episodes == 5 and buf.episodes_added == 7
    s = buf.sample(5_000)
    assert_consistent(s, 5_000)
    assert set(decode(s)[0]) == set(range(ID0 + 2, ID0 + 7))  # the two oldest are gone
    buf.add_episodes(*batch(range(ID0 + 7, ID0 + 19)))  # more than capacity in one call
    assert set(decode(buf.sample(5_000))[0]) == set(range(ID0 + 14, ID0 + 19))
    assert buf.episodes_added == 19


def test_sample_many_is_one_flat_gather() -> None:
    a, b = make(seed=3), make(seed=3)
    for buf in (a, b):
        buf.add_episodes(*batch(range(ID0, ID0 + 8)))
    many, flat = a.sample_many(40, 16), b.sample(640)
    assert many.keys() == flat.keys()
    for k in many:
        np.testing.assert_array_equal(many[k], flat[k])
    assert_consistent(many, 640)


def test_seeded_sampling_is_reproducible() -> None:
    out = []
    for seed in (7, 7, 8):
        buf = make(seed=seed)
        buf.add_episodes(*batch(range(ID0, ID0 + 10)))
        out.append([buf.sample(64) for _ in range(3)])
    for s7, s7b, s8 in zip(*out):
        assert all(np.array_equal(s7[k], s7b[k]) for k in s7)
        assert not np.array_equal(s7["obs/robot_state"], s8["obs/robot_state"])


def test_input_validation() -> None:
    buf = make()
    obs, act = batch([ID0, ID0 + 1])
    with pytest.raises(ValueError, match="keys"):
        buf.add_episodes({k: v for k, v in obs.items() if k != "task_state"}, act)
    with pytest.raises(ValueError, match="actions shape"):
        buf.add_episodes(obs, act[:, :-1])
    with pytest.raises(ValueError, match="robot_state"):
        buf.add_episodes({**obs, "robot_state": obs["robot_state"][:1]}, act)
    with pytest.raises(RuntimeError, match="empty"):
        buf.sample(4)
    with pytest.raises(ValueError, match="not in obs_spec"):
        HindsightReplay({"x": ((3,), np.float32)}, A, T, 4, reward_fn)


# ---------------------------------------------------------------------------------- checkpoints
def filled(capacity: int, n: int, seed: int = 1) -> HindsightReplay:
    buf = make(capacity=capacity, seed=seed)
    buf.add_episodes(*batch(range(ID0, ID0 + n)))
    buf.sample(33)  # advance the RNG so its state matters
    return buf


@pytest.mark.parametrize("capacity,n", [(10, 4), (5, 7)])  # partial fill; wrapped ring
def test_save_load_round_trip_continues_identically(tmp_path: Path, capacity: int, n: int) -> None:
    buf = filled(capacity, n)
    path = tmp_path / "replay.ckpt"  # no .npz suffix: save must write exactly this path
    buf.save(path)
    assert path.exists() and not list(tmp_path.glob("*.tmp"))
    restored = HindsightReplay.from_file(path, reward_fn)
    into = make(capacity=capacity, seed=999)
    into.add_episodes(*batch(range(ID0 + 50, ID0 + 50 + capacity)))  # stale content must go
    into.load(path)
    for other in (restored, into):
        assert (other.num_episodes, other.episodes_added) == (buf.num_episodes, buf.episodes_added)
        assert other.nbytes == buf.nbytes
    expected = [buf.sample(50) for _ in range(3)]
    for other in (restored, into):
        for e in expected:
            got = other.sample(50)
            assert all(np.array_equal(got[k], e[k]) for k in e)
    # adding after restore lands in the same slot as it would have originally: the same samples
    for b in (buf, restored):
        b.add_episodes(*batch([ID0 + 500]))
    again = [buf.sample(50) for _ in range(3)]
    for e in again:
        got = restored.sample(50)
        assert all(np.array_equal(got[k], e[k]) for k in e)


class _Boom:
    def __reduce__(self):  # unpickling this would record that pickle ran
        return (Path.touch, (Path(_Boom.marker),))


def test_load_rejects_corrupt_foreign_and_pickled_files(tmp_path: Path) -> None:
    good = tmp_path / "good.npz"
    filled(10, 4).save(good)
    raw = good.read_bytes()
    marker = tmp_path / "unpickled"
    _Boom.marker = str(marker)

    cases: dict[str, bytes | None] = {
        "garbage.npz": b"this is not a numpy file at all" * 10,
        "truncated.npz": raw[: len(raw) // 2],
        "pickled.npz": pickle.dumps({"meta": _Boom()}),
    }
    for name, data in cases.items():
        (tmp_path / name).write_bytes(data)
    np.savez(tmp_path / "foreign.npz", weights=np.ones(3))
    np.savez(tmp_path / "objects.npz", meta=np.array([_Boom()], dtype=object))
    np.save(tmp_path / "bare.npy", np.ones(3))
    with np.load(good) as z:
        np.savez(tmp_path / "missing.npz", **{k: z[k] for k in z.files if k != "actions"})
        arrays = {k: z[k] for k in z.files}
    np.savez(tmp_path / "badshape.npz", **{**arrays, "actions": arrays["actions"][:-1]})
    np.savez(tmp_path / "badformat.npz", **{**arrays, "meta": np.array('{"format": "other/9"}')})

    loaders = (lambda p: make(capacity=10).load(p), lambda p: HindsightReplay.from_file(p, reward_fn))
    written = ["foreign.npz", "objects.npz", "bare.npy", "missing.npz", "badshape.npz", "badformat.npz"]
    for name in [*cases, *written]:
        path = tmp_path / name
        for loader in loaders:
            with pytest.raises(ValueError, match="not a valid HindsightReplay checkpoint") as info:
                loader(path)
            assert str(path) in str(info.value), name
    assert not marker.exists(), "load unpickled something"

    with pytest.raises(ValueError, match="capacity_episodes"):
        make(capacity=11).load(good)
    with pytest.raises(FileNotFoundError):
        make().load(tmp_path / "absent.npz")
