"""Tests for ps_ray.data.anchors: real scikit-learn, real files, a tiny env; all fast."""

from __future__ import annotations

import json
import os
import pickle
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest
from sklearn.cluster import KMeans
from sklearn.metrics import pairwise_distances_argmin_min

from ps_ray.data import anchors as A
from ps_ray.data.anchor_file import anchors_from_file, load_anchor_set, save_anchor_set
from ps_ray.data.anchors import (
    AnchorSet,
    anchor_hash,
    make_anchor_set,
    select_anchor_indices,
    select_anchors,
)
from ps_ray.data.collect import collect_task_states
from tests.point_env import PointGoalEnv


def blobs(n_blobs: int = 5, per_blob: int = 40, dim: int = 3, seed: int = 0):
    """Well-separated Gaussian blobs, shuffled; returns (states float32, blob label per row)."""
    rng = np.random.default_rng(seed)
    centers = np.arange(n_blobs)[:, None] * 10.0 + np.zeros(dim)
    x = np.concatenate([c + rng.normal(0, 0.5, (per_blob, dim)) for c in centers])
    labels = np.repeat(np.arange(n_blobs), per_blob)
    perm = rng.permutation(len(x))
    return x[perm].astype(np.float32), labels[perm]


def row_index(states: np.ndarray, row: np.ndarray) -> int:
    hits = np.flatnonzero((states == row).all(axis=1))
    assert len(hits) >= 1, "anchor is not a row of the input"
    return int(hits[0])


# --------------------------------------------------------------------------- selection


def test_one_anchor_per_blob_nearest_member_to_its_centroid():
    x, labels = blobs()
    anchors = select_anchors(x, 5)
    assert anchors.shape == (5, 3) and anchors.dtype == np.float32
    idx = [row_index(x, a) for a in anchors]
    assert sorted(labels[idx]) == [0, 1, 2, 3, 4]  # exactly one per blob
    for i in idx:  # the blob's member closest to the blob's centroid (= its k-means centroid)
        members = np.flatnonzero(labels == labels[i])
        centroid = x[members].astype(np.float64).mean(axis=0)
        nearest = members[np.argmin(np.linalg.norm(x[members] - centroid, axis=1))]
        assert i == nearest


@pytest.mark.e2e
def test_anchors_do_not_depend_on_the_thread_count():
    """Reach's task states (200 goals, each recorded at 5 steps) under k-means on 1 and 2 OpenMP
    threads gave anchors 0.03 apart, so a seed's anchors depended on the machine and on what ran
    before in the process. Selection pins one thread: the caller's thread limits change nothing."""
    from threadpoolctl import threadpool_limits

    from ps_ray.envs.core import RobotTaskEnv

    states = collect_task_states(lambda: RobotTaskEnv(robot="panda", task="reach"), episodes=200, seed=0)
    picked = []
    for threads in (1, 2):
        with threadpool_limits(limits=threads):
            picked.append(select_anchors(states, 128, seed=0))
    np.testing.assert_array_equal(picked[0], picked[1])


def test_matches_the_authors_rule_and_is_deterministic():
    rng = np.random.default_rng(1)
    x = rng.normal(size=(200, 15)).astype(np.float32)
    idx = select_anchor_indices(x, 16, seed=0, n_init=3)
    ours = select_anchors(x, 16, seed=0, n_init=3)
    np.testing.assert_array_equal(x[idx], ours)  # deterministic under the seed
    centers = KMeans(n_clusters=16, random_state=0, n_init=3).fit(x).cluster_centers_
    theirs = x[pairwise_distances_argmin_min(centers, x)[0]]
    np.testing.assert_array_equal(ours, theirs)  # no collision here: identical to the authors
    assert len(np.unique(ours, axis=0)) == 16


def test_distinct_false_keeps_the_authors_duplicates():
    # 3 distinct rows but heavy duplicates: still fine; distinct=False is the raw rule
    dup = np.repeat(np.eye(3, dtype=np.float32), 10, axis=0)
    raw = select_anchors(dup, 3, distinct=False, n_init=2)
    centers = KMeans(n_clusters=3, random_state=0, n_init=2).fit(dup).cluster_centers_
    np.testing.assert_array_equal(raw, dup[pairwise_distances_argmin_min(centers, dup)[0]])


def test_float64_input_gives_float32_rows_of_the_cast_input():
    x, _ = blobs(dim=4)
    anchors = select_anchors(x.astype(np.float64), 5)
    assert anchors.dtype == np.float32
    for a in anchors:
        row_index(x, a)


def test_colliding_centroids_get_distinct_nearest_rows():
    states = np.array([[0.0, 0.0], [1.0, 0.0], [3.0, 0.0], [0.0, 0.0]], np.float32)
    centers = np.array([[0.2, 0.0], [0.1, 0.0], [2.9, 0.0]], np.float32)
    idx, dist = pairwise_distances_argmin_min(centers, states)
    assert idx[0] == idx[1] == 0  # both want the origin
    out = A.distinct_nearest_rows(centers, states, idx, dist)
    # centroid 1 is closer to the origin and keeps it; centroid 0 takes its nearest free row
    # ([1, 0]), not the duplicate origin at row 3
    np.testing.assert_array_equal(states[out], [[1, 0], [0, 0], [3, 0]])


def test_too_few_states_is_a_clear_error():
    x, _ = blobs(n_blobs=2, per_blob=2)
    with pytest.raises(ValueError, match="cannot select 5 anchors from 4 states"):
        select_anchors(x, 5)
    dup = np.repeat(np.eye(3, dtype=np.float32), 10, axis=0)  # 30 rows, 3 distinct
    with pytest.raises(ValueError, match="only 3 distinct rows"):
        select_anchors(dup, 4)
    assert len(np.unique(select_anchors(dup, 3), axis=0)) == 3
    with pytest.raises(ValueError, match="k must be a positive integer"):
        select_anchors(x, 0)
    with pytest.raises(ValueError, match=r"\(N, dim\) matrix"):
        select_anchors(np.zeros(10, np.float32), 2)
    with pytest.raises(ValueError, match="NaN"):
        select_anchors(np.full((10, 2), np.nan), 2)


# --------------------------------------------------------------------------- hashing


def test_hash_stable_sensitive_and_shape_aware():
    a = np.arange(12, dtype=np.float32).reshape(4, 3) / 7
    h = anchor_hash(a)
    assert len(h) == 64 and h == anchor_hash(a.copy())
    assert h == anchor_hash(np.asfortranarray(a)) == anchor_hash(a.astype(">f4"))
    for i in np.ndindex(a.shape):
        b = a.copy()
        b[i] = np.nextafter(b[i], np.float32(np.inf))
        assert anchor_hash(b) != h
    assert anchor_hash(a.reshape(3, 4)) != h
    assert anchor_hash(a.reshape(12, 1)) != h
    assert anchor_hash(a[:3]) != h
    assert anchor_hash(np.zeros((2, 2), np.float32)) == anchor_hash(-np.zeros((2, 2), np.float32))


@pytest.mark.e2e
def test_hash_is_pinned_and_identical_in_a_fresh_process():
    # Pinned: changing the encoding would orphan every stored anchor set and module signature.
    a = np.array([[0.5, -1.0, 2.0], [3.25, 0.0, -4.5]], np.float32)
    golden = "8e3c5d5e69989676ce157404dd851f4b18f18eda46ad82bab215336e8533e521"
    code = (
        "import numpy as np; from ps_ray.data.anchors import anchor_hash; "
        "print(anchor_hash(np.array([[0.5, -1.0, 2.0], [3.25, 0.0, -4.5]], np.float32)))"
    )
    env = dict(os.environ, PYTHONHASHSEED="123")
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, env=env
    ).stdout.strip()
    assert out == anchor_hash(a)
    assert anchor_hash(a) == golden


# --------------------------------------------------------------------------- files


@pytest.fixture(scope="module")
def anchor_set():
    x, _ = blobs()
    return make_anchor_set(
        {"push": x[:120], "push_slippery": x[120:]}, 5, extra_provenance={"steps": (5, 6, 7, 8, 9)}
    )


def test_anchor_set_contents(anchor_set):
    assert anchor_set.k == 5 and anchor_set.dim == 3
    assert anchor_set.hash == anchor_hash(anchor_set.anchors)
    assert not anchor_set.anchors.flags.writeable
    prov = anchor_set.provenance
    assert prov["sources"] == {"push": 120, "push_slippery": 80} and prov["num_states"] == 200
    assert prov["steps"] == [5, 6, 7, 8, 9]
    assert {"k", "seed", "n_init", "versions"} <= set(prov) and "sklearn" in prov["versions"]
    with pytest.raises(ValueError, match="does not match"):
        AnchorSet(anchor_set.anchors, "0" * 64, {})
    with pytest.raises(ValueError, match="JSON"):
        AnchorSet.of(anchor_set.anchors, {"bad": object()})


def test_save_load_round_trip_is_exact_and_atomic(tmp_path, anchor_set):
    path = tmp_path / "anchors.npz"
    save_anchor_set(path, anchor_set)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["anchors.npz"]  # no temp leftovers
    loaded = load_anchor_set(path)
    assert loaded == anchor_set
    np.testing.assert_array_equal(loaded.anchors, anchor_set.anchors)
    assert loaded.anchors.dtype == np.float32 and loaded.provenance == anchor_set.provenance
    with np.load(path, allow_pickle=False) as npz:  # loadable by plain numpy, no pickle
        assert sorted(npz.files) == ["anchors", "meta"]
    save_anchor_set(str(path), loaded)  # overwrite in place
    assert load_anchor_set(path) == anchor_set


def test_failed_save_leaves_old_file_and_no_debris(tmp_path, anchor_set, monkeypatch):
    path = tmp_path / "anchors.npz"
    save_anchor_set(path, anchor_set)
    before = path.read_bytes()

    def half_write(fh, **arrays):
        fh.write(b"PK\x03\x04 half")
        raise OSError("disk full")

    monkeypatch.setattr(A.np, "savez", half_write)
    with pytest.raises(OSError, match="disk full"):
        save_anchor_set(path, anchor_set)
    monkeypatch.undo()
    assert path.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["anchors.npz"]


def _rewrite(path: Path, **members) -> None:
    with open(path, "wb") as fh:
        np.savez(fh, **members)


def _members(path: Path) -> dict:
    with np.load(path, allow_pickle=False) as npz:
        return {k: npz[k] for k in npz.files}


class _Boom:
    """Unpickling this creates a marker file: proves whether anything was unpickled."""

    def __init__(self, marker: Path):
        self.marker = marker

    def __reduce__(self):
        return (Path.touch, (self.marker,))


@pytest.mark.parametrize(
    "case",
    [
        "tampered_array",
        "tampered_hash",
        "garbage",
        "truncated",
        "empty",
        "pickle_file",
        "pickle_member",
        "missing_meta",
        "missing_anchors",
        "extra_member",
        "plain_npy",
        "bad_json",
        "foreign_format",
        "float64_anchors",
    ],
)
def test_bad_files_are_one_line_value_errors_naming_the_file(tmp_path, anchor_set, case):
    path = tmp_path / f"{case}.npz"
    save_anchor_set(path, anchor_set)
    m = _members(path)
    marker = tmp_path / "unpickled"
    expect = {
        "tampered_array": "hash mismatch",
        "tampered_hash": "hash mismatch",
        "garbage": "not an .npz",
        "truncated": "unreadable",
        "empty": "not an .npz",
        "pickle_file": "not an .npz",
        "pickle_member": "pickled",
        "missing_meta": "missing",
        "missing_anchors": "missing",
        "extra_member": "unexpected",
        "plain_npy": "plain .npy",
        "bad_json": "JSON",
        "foreign_format": "does not describe",
        "float64_anchors": "float32",
    }[case]
    if case == "tampered_array":
        arr = m["anchors"].copy()
        arr[2, 1] += 1e-3
        _rewrite(path, anchors=arr, meta=m["meta"])
    elif case == "tampered_hash":
        meta = json.loads(str(m["meta"]))
        meta["hash"] = "f" * 64
        _rewrite(path, anchors=m["anchors"], meta=np.array(json.dumps(meta)))
    elif case == "garbage":
        path.write_bytes(os.urandom(300).replace(b"PK", b"xx"))
    elif case == "truncated":
        path.write_bytes(path.read_bytes()[:200])
    elif case == "empty":
        path.write_bytes(b"")
    elif case == "pickle_file":
        path.write_bytes(pickle.dumps(_Boom(marker)))
    elif case == "pickle_member":
        obj = np.empty(1, dtype=object)
        obj[0] = _Boom(marker)
        _rewrite(path, anchors=obj, meta=m["meta"])
    elif case == "missing_meta":
        _rewrite(path, anchors=m["anchors"])
    elif case == "missing_anchors":
        _rewrite(path, meta=m["meta"])
    elif case == "extra_member":
        _rewrite(path, anchors=m["anchors"], meta=m["meta"], other=np.zeros(2))
    elif case == "plain_npy":
        np.save(path.with_suffix(".npy"), m["anchors"])
        path = path.with_suffix(".npy")
    elif case == "bad_json":
        _rewrite(path, anchors=m["anchors"], meta=np.array("{not json"))
    elif case == "foreign_format":
        _rewrite(path, anchors=m["anchors"], meta=np.array(json.dumps({"format": "other"})))
    elif case == "float64_anchors":
        _rewrite(path, anchors=m["anchors"].astype(np.float64), meta=m["meta"])
    with pytest.raises(ValueError) as info:
        load_anchor_set(path)
    msg = str(info.value)
    assert msg.startswith(f"{path}: ") and "\n" not in msg, msg
    assert expect in msg, msg
    assert not marker.exists()


def test_zip_of_non_npy_is_rejected(tmp_path):
    path = tmp_path / "foreign.npz"
    with zipfile.ZipFile(path, "w") as zf:
        zf.writestr("anchors.npy", b"not an npy payload")
        zf.writestr("meta.npy", b"nor this")
    with pytest.raises(ValueError, match="foreign.npz: unreadable"):
        load_anchor_set(path)


def test_missing_file_is_file_not_found(tmp_path):
    with pytest.raises(FileNotFoundError):
        load_anchor_set(tmp_path / "nope.npz")


# --------------------------------------------------------------------------- anchors_from_file


def test_anchors_from_file_accepts_anchor_sets_and_plain_state_arrays(tmp_path, anchor_set):
    x, _ = blobs()
    set_path = tmp_path / "set.npz"
    save_anchor_set(set_path, anchor_set)
    assert anchors_from_file(set_path, 5) == anchor_set
    with pytest.raises(ValueError, match="set.npz: anchor set has 5 anchors, 4 requested"):
        anchors_from_file(set_path, 4)

    npy = tmp_path / "states.npy"
    np.save(npy, x.astype(np.float64))  # the authors' task_state_list.npy is float64
    got = anchors_from_file(npy, 5)
    np.testing.assert_array_equal(got.anchors, select_anchors(x, 5))
    assert got.provenance["source_file"] == str(npy) and got.provenance["num_states"] == 200
    assert len(got.provenance["source_sha256"]) == 64

    single = tmp_path / "single.npz"
    np.savez(single, whatever=x)
    np.testing.assert_array_equal(anchors_from_file(single, 5).anchors, got.anchors)
    named = tmp_path / "named.npz"
    np.savez(named, states=x, episodes=np.arange(3))
    assert anchors_from_file(named, 5).provenance["source_member"] == "states"


def test_anchors_from_file_rejects_bad_state_files(tmp_path):
    x, _ = blobs(n_blobs=2, per_blob=2)
    cases = {
        "few.npy": (lambda p: np.save(p, x), "4 task states, fewer than the 5"),
        "vec.npy": (lambda p: np.save(p, x[:, 0]), r"\(N, dim\) matrix"),
        "two.npz": (lambda p: np.savez(p, a=x, b=x), "expected one array"),
        "obj.npy": (lambda p: np.save(p, np.array([{"a": 1}] * 8, dtype=object)), "pickled"),
        "text.npy": (lambda p: p.write_text("1,2,3\n4,5,6\n"), "neither an .npy nor an .npz"),
    }
    for name, (write, expect) in cases.items():
        path = tmp_path / name
        write(path)
        with pytest.raises(ValueError, match=expect) as info:
            anchors_from_file(path, 5)
        assert str(info.value).startswith(f"{path}: ")


# --------------------------------------------------------------------------- collection


class CountingEnv(PointGoalEnv):
    """PointGoalEnv whose task_state is the step counter, so recorded steps are visible."""

    def __init__(self, horizon: int = 20):
        super().__init__(horizon)  # positional: the keyword's name is not part of the contract
        import gymnasium as gym

        spaces = dict(self.observation_space.spaces)
        spaces["task_state"] = gym.spaces.Box(0, 1000, (1,), np.float32)
        self.observation_space = gym.spaces.Dict(spaces)

    def _obs(self):
        obs = super()._obs()
        obs["task_state"] = np.array([self._t], np.float32)
        return obs


def test_collect_on_point_env_shape_and_determinism():
    states = collect_task_states(PointGoalEnv, episodes=6, seed=3)
    assert states.shape == (30, 2) and states.dtype == np.float32
    np.testing.assert_array_equal(states, collect_task_states(PointGoalEnv, episodes=6, seed=3))
    assert not np.array_equal(states, collect_task_states(PointGoalEnv, episodes=6, seed=4))
    for ep in range(6):  # task input = desired_goal of the episode reset with seed + ep
        goal = PointGoalEnv().reset(seed=3 + ep)[0]["desired_goal"]
        np.testing.assert_array_equal(states[5 * ep : 5 * ep + 5], np.tile(goal, (5, 1)))


def test_collect_records_steps_5_to_9_and_calls_policy_batched():
    calls = []

    def policy(obs):
        assert set(obs) == {"robot_state", "task_state", "achieved_goal", "desired_goal"}
        assert obs["robot_state"].shape == (1, 2) and obs["desired_goal"].shape == (1, 2)
        calls.append(int(obs["task_state"][0, 0]))
        return np.ones((1, 2), np.float32)

    states = collect_task_states(CountingEnv, episodes=3, policy=policy)
    assert states.shape == (15, 3)  # task_state (1) + desired_goal (2)
    np.testing.assert_array_equal(states[:, 0], np.tile([5, 6, 7, 8, 9], 3))
    assert calls == list(range(9)) * 3  # episodes stop after the last recorded step
    custom = collect_task_states(CountingEnv, episodes=2, steps=[0, 19, 3])
    np.testing.assert_array_equal(custom[:, 0], [0, 3, 19, 0, 3, 19])


def test_collect_errors():
    with pytest.raises(ValueError, match="ended after 7 steps"):
        collect_task_states(lambda: CountingEnv(horizon=7), episodes=1)
    with pytest.raises(ValueError, match="shape \\(1, A\\)"):
        collect_task_states(PointGoalEnv, episodes=1, policy=lambda obs: np.zeros(2))
    with pytest.raises(ValueError, match="episodes"):
        collect_task_states(PointGoalEnv, episodes=0)
    with pytest.raises(ValueError, match="distinct"):
        collect_task_states(PointGoalEnv, episodes=1, steps=[5, 5])
    with pytest.raises(ValueError, match="non-negative"):
        collect_task_states(PointGoalEnv, episodes=1, steps=[-1])


def test_relabelled_goals_are_later_achieved_goals_of_the_same_episode():
    """On the marker family every real desired goal is the zero offset; relabelled ones are what
    hindsight relabelling feeds the task module: achieved goals of later steps."""
    from ps_ray.envs import make

    markers = lambda: make("panda", "reach_red")  # noqa: E731
    real = collect_task_states(markers, episodes=3, seed=7)
    relabelled = collect_task_states(markers, episodes=3, seed=7, goals="relabelled")
    np.testing.assert_array_equal(real[:, -3:], 0.0)
    np.testing.assert_array_equal(relabelled[:, :-3], real[:, :-3])  # the scene is kept
    for ep in range(3):  # replay each episode with the same seeds and collect its achieved goals
        env = make("panda", "reach_red")
        obs, _ = env.reset(seed=7 + ep)
        env.action_space.seed(7 + ep)
        achieved, done = [obs["achieved_goal"]], False
        while not done:
            obs, _, terminated, truncated, _ = env.step(env.action_space.sample())
            achieved.append(obs["achieved_goal"])
            done = terminated or truncated
        env.close()
        for row, step in zip(relabelled[5 * ep : 5 * ep + 5], range(5, 10)):
            assert any(np.array_equal(row[-3:], goal) for goal in achieved[step + 1 :])
            assert np.linalg.norm(row[-3:]) > 0.05  # nowhere near the real goal
    again = collect_task_states(markers, episodes=3, seed=7, goals="relabelled")
    np.testing.assert_array_equal(again, relabelled)
    with pytest.raises(ValueError, match="^unknown goals 'future'; valid goals: real, relabelled$"):
        collect_task_states(PointGoalEnv, episodes=1, goals="future")


def test_collect_then_select_end_to_end(tmp_path):
    states = collect_task_states(CountingEnv, episodes=20, seed=0)
    aset = make_anchor_set({"counting": states}, 8, extra_provenance={"steps": [5, 6, 7, 8, 9]})
    for a in aset.anchors:
        row_index(states, a)
    save_anchor_set(tmp_path / "a.npz", aset)
    assert load_anchor_set(tmp_path / "a.npz").hash == aset.hash
