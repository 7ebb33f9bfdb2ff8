"""Pairs of task states matched by meaning, to fit a latent translation on or to re-anchor a
relative projection with (docs/transfer.md, "Translations fitted on matched pairs", "Anchors
matched by meaning").

A translation fitted on the *same* task states through two task modules makes one task's module
read a scene as the other task reads it: on the marker family, exactly the difference the target
needs. Relative representations and latent translation (Maiorca et al. 2023) assume *parallel*
data instead: inputs that mean the same in both spaces. Three ways to pair a task-X scene with a
task-Y scene, each spelt as a translation's fit (``affine@outcome``):

- ``outcome``: roll out each task's own trained source on scenes disjoint from evaluation
  (:data:`OUTCOME_SEED`), keep the successful episodes, describe each by where it ended (world
  frame: the object, in a task with one such as push; else the end effector; the env's target is
  never read), pick reference points by k-means over the pooled end points, and pair, per point,
  the X scene and the Y scene whose end points are nearest;
- ``shuffled``: the same pairs with the Y side permuted (a control: as many pairs, no meaning);
- ``swapped``: the known correspondence of the marker family, each X scene with the scene whose
  two tasks' markers trade places (an upper bound no outcome matching can beat).

Re-anchoring (``anchors@outcome``, :func:`matched_anchors`) keeps the robot module's anchors as
they are and gives the task module, per anchor, the X scene that means what the anchor means to
the robot source's task: the robot source is rolled out from each anchor's scene, and the X scene
whose outcome is nearest its end point takes the anchor's place. Re-anchoring may also read both
sources' outcomes in every scene (``anchors@both``: the nearest candidate, ``anchors@decoded``: an
affine decoding between the candidates).
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

from ps_ray.envs.tasks import resolve_task
from ps_ray.envs.tasks.markers import MarkerScene
from ps_ray.errors import UserError
from ps_ray.specs import reset_seeds
from ps_ray.specs.names import ANCHOR_FITS, CROSSED_FITS, EnvPart, parse_spec_text
from ps_ray.store.atomic import atomic_file
from ps_ray.store.npz import read_npz

OUTCOME_SEED = reset_seeds.fixed("outcomes")  # first reset seed of the outcome rollouts


@dataclass(frozen=True)
class Outcomes:
    """The successful greedy episodes of one policy in its own env."""

    task_in: np.ndarray  # (N, task_dim): the task input at reset
    end: np.ndarray  # (N, 3): where each episode ended, world frame (evaluate.outcome_point)


def outcomes(policy, robot, task, scenes: int) -> Outcomes:
    """Greedy rollouts of a policy (anything :func:`ps_ray.stitching.evaluate.evaluate` takes) in its own
    env from ``scenes`` reset seeds starting at :data:`OUTCOME_SEED`: the successful ones, each
    described by its first task input and where it ended (:func:`ps_ray.stitching.evaluate.outcome_point`:
    the object, or the end effector in a task without one; the env's target is never read: success
    only decides which episodes are kept)."""
    from ps_ray.stitching.evaluate import evaluate, outcome_point

    result = evaluate(policy, robot, task, episodes=scenes, repeats=1, seed=OUTCOME_SEED)
    won = [r for r in result["records"] if r["success"]]
    if len(won) < 2:
        raise UserError(f"{policy}: {len(won)} of {scenes} outcome rollouts succeeded; too few to match")
    return Outcomes(
        np.array([r["task_input"] for r in won], np.float32), np.array([outcome_point(r) for r in won])
    )


@lru_cache(maxsize=16)
def _source_outcomes(path: str, robot: str, task: str, scenes: int, cache: str | None) -> Outcomes:
    """:func:`outcomes` of a policy file in its env (spec texts), cached per process (the pairs
    of a zero-shot batch share their sources) and, given a ``cache`` folder, on disk, keyed by the
    file's bytes, its env and the scenes (every batch of a stage reads the same sources)."""
    # an object task's outcome is where its object ended (before, its end effector's end): its own key
    kind = "|object" if resolve_task(parse_spec_text(task)).family.has_object else ""
    found = _disk_cached(
        cache,
        (path, f"|{robot}|{task}|{scenes}|{OUTCOME_SEED}{kind}".encode()),
        lambda: vars(outcomes(path, parse_spec_text(robot), parse_spec_text(task), scenes)),
    )
    return Outcomes(found["task_in"], found["end"])


def anchor_ends(policy, robot, task, anchors: np.ndarray) -> np.ndarray:
    """Where a policy's greedy rollouts in its env end (world frame), one per anchor, each reset to
    the anchor's scene; every episode is kept (success is not read, nor is the env's target)."""
    from ps_ray.stitching.evaluate import evaluate, outcome_point

    result = evaluate(
        policy, robot, task, episodes=len(anchors), repeats=1, seed=OUTCOME_SEED, scenes=anchors
    )
    return np.array([outcome_point(r) for r in result["records"]])


def fit_env_steps(kind: str, fit: str, scenes: int, anchors: int = 0, candidates: int = 0) -> int:
    """Env steps the fit of ``<kind>@<fit>`` rolls out (whether or not a cache spares them): each
    rollout is one episode of ``EPISODE_STEPS``. ``scenes``: rollouts per source for outcomes;
    ``anchors``: the robot module's anchors (re-anchoring); ``candidates``: the task source's
    successful outcome scenes (the crossed fits roll the robot source out on each)."""
    from ps_ray.envs.core import EPISODE_STEPS

    if kind != "anchors":  # both sources' outcomes, for every fit (swapped pairs the X side)
        episodes = 2 * scenes
    elif fit == "swapped":  # the known correspondence: no rollout
        episodes = 0
    elif fit in CROSSED_FITS:  # the task source's outcomes, the robot source on them, both on the anchors
        episodes = scenes + candidates + 2 * anchors
    else:  # the task source's outcomes and the robot source on the anchors
        episodes = scenes + anchors
    return episodes * EPISODE_STEPS


def fit_cost(
    kind: str,
    fit: str,
    task_source: tuple[str, EnvPart, EnvPart],
    scenes: int,
    anchors: int,
    cache: str | None,
) -> int:
    """:func:`fit_env_steps` of a pair's fit, its candidates counted from the task source's
    outcomes (the cached rollouts the fit itself read)."""
    candidates = 0
    if kind == "anchors" and fit in CROSSED_FITS:
        path, robot, task = task_source
        candidates = len(_source_outcomes(path, robot.text, task.text, scenes, cache).task_in)
    return fit_env_steps(kind, fit, scenes, anchors, candidates)


def match_anchors(mine: Outcomes, ends: np.ndarray) -> np.ndarray:
    """Per point (an anchor's end point, a reference point), the task input of ``mine`` whose
    outcome is nearest it."""
    return mine.task_in[np.linalg.norm(mine.end[None, :, :] - ends[:, None, :], axis=-1).argmin(axis=1)]


def match_anchors_by_both(
    mine: Outcomes, theirs_on_mine: np.ndarray, theirs: np.ndarray, mine_on_anchors: np.ndarray
) -> np.ndarray:
    """Per anchor, the task input of ``mine`` whose two outcomes match the anchor's crossed over:
    where the task source ends in it nearest where the robot source ends in the anchor
    (``theirs``), and where the robot source ends in it (``theirs_on_mine``) nearest where the task
    source ends in the anchor (``mine_on_anchors``). One outcome reveals what a scene means to one
    task; both reveal the whole scene, so the match is the anchor with the meanings traded."""
    cost = np.linalg.norm(mine.end[None, :, :] - theirs[:, None, :], axis=-1)
    cost += np.linalg.norm(theirs_on_mine[None, :, :] - mine_on_anchors[:, None, :], axis=-1)
    return mine.task_in[cost.argmin(axis=1)]


def decode_anchors(
    mine: Outcomes, theirs_on_mine: np.ndarray, theirs: np.ndarray, mine_on_anchors: np.ndarray
) -> np.ndarray:
    """Per anchor, the task input decoded from the outcomes :func:`match_anchors_by_both` matches
    on: the scene in which the task source would end where the robot source ends in the anchor
    (``theirs``) and the robot source where the task source ends in it (``mine_on_anchors``), by an
    affine map from a scene's two outcomes to the scene, fitted by least squares on the candidate
    scenes (``mine``, ``theirs_on_mine``). It reads between the candidates instead of taking the
    nearest (docs/notebook/transfer_log.md, "Anchors matched by meaning": closer to the known correspondence,
    and no better zero-shot: its scenes need not be ones the task module saw). Unlike the latent
    translation it needs no ridge: 7 unknowns per output (two 3-D outcomes and an offset) from
    hundreds of candidate scenes, far from the rows-equal-unknowns peak of least squares."""
    from sklearn.linear_model import LinearRegression

    decoder = LinearRegression().fit(np.c_[mine.end, theirs_on_mine], mine.task_in)
    return decoder.predict(np.c_[theirs, mine_on_anchors]).astype(np.float32)


@lru_cache(maxsize=16)
def _source_anchor_ends(
    path: str, robot: str, task: str, anchors: bytes, task_dim: int, cache: str | None
) -> np.ndarray:
    """:func:`anchor_ends` of a policy file in its env (spec texts), cached as
    :func:`_source_outcomes` is."""
    scenes = np.frombuffer(anchors, np.float32).reshape(-1, task_dim)
    key = f"|{robot}|{task}|anchor ends|{OUTCOME_SEED}|{scenes.shape}|".encode() + anchors
    ends = _disk_cached(
        cache,
        (path, key),
        lambda: {"end": anchor_ends(path, parse_spec_text(robot), parse_spec_text(task), scenes)},
    )["end"]
    if ends.shape != (len(scenes), 3):  # a bug, never bad input: the key names the scenes
        raise RuntimeError(f"{path}: cached anchor ends of shape {ends.shape} for {len(scenes)} anchors")
    return ends


def _disk_cached(cache: str | None, key: tuple[str, bytes], compute) -> dict[str, np.ndarray]:
    """``compute()`` (a dict of arrays), kept in ``cache`` (a folder) under a hash of the policy
    file's bytes and ``key``'s bytes; computed every time without a folder."""
    if cache is None:
        return compute()
    digest = hashlib.sha256(Path(key[0]).read_bytes())
    digest.update(key[1])
    file = Path(cache) / f"{digest.hexdigest()[:20]}.npz"
    if file.is_file():
        return read_npz(file)
    found = compute()
    file.parent.mkdir(parents=True, exist_ok=True)
    with atomic_file(file) as f:
        np.savez(f, **found)
    return found


def matched_pairs(a: Outcomes, b: Outcomes, points: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """(X states, Y states), row i of each the scene whose end point is nearest reference point i
    (k-means over the pooled end points; at most as many points as the smaller side has)."""
    from sklearn.cluster import KMeans

    pooled = np.concatenate([a.end, b.end])
    k = min(points, len(a.end), len(b.end))
    centres = KMeans(n_clusters=k, n_init=4, random_state=seed).fit(pooled).cluster_centers_
    return match_anchors(a, centres), match_anchors(b, centres)


def colour_swapped(states: np.ndarray, task_from: EnvPart, task_to: EnvPart) -> np.ndarray:
    """Task inputs of ``task_from`` (a marker task) with its marker and ``task_to``'s trading
    places: the scene in which ``task_to`` means what ``task_from`` means in the original."""
    spec_from, spec_to = resolve_task(task_from), resolve_task(task_to)
    family = spec_from.family
    if not (issubclass(family, MarkerScene) and spec_to.family is family):
        raise UserError(
            f"swapped pairs need two tasks of one marker family, got {task_from.short} and {task_to.short}"
        )
    a, b = family.marker_columns(spec_from.options.target), family.marker_columns(spec_to.options.target)
    out = np.array(states, np.float32, copy=True)
    out[:, a], out[:, b] = states[:, b], states[:, a]
    return out


def fit_pairs(
    fit: str,
    task_source: tuple[str, EnvPart, EnvPart],
    robot_source: tuple[str, EnvPart, EnvPart],
    scenes: int,
    points: int,
    seed: int = 0,
    cache: str | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """The (task module's states, robot source's task module's states) a translation of the
    given ``fit`` is fitted on; each source given as (policy file, its robot, its task); their
    rollouts kept in ``cache`` (a folder), if given."""
    mine = _source_outcomes(task_source[0], task_source[1].text, task_source[2].text, scenes, cache)
    theirs = _source_outcomes(robot_source[0], robot_source[1].text, robot_source[2].text, scenes, cache)
    states_t, states_r = matched_pairs(mine, theirs, points, seed)
    if fit == "shuffled":
        states_r = states_r[np.random.default_rng(seed).permutation(len(states_r))]
    elif fit == "swapped":
        states_r = colour_swapped(states_t, task_source[2], robot_source[2])
    elif fit != "outcome":
        raise ValueError(f"unknown fit {fit!r}")
    return states_t, states_r


def matched_anchors(
    fit: str,
    anchors: np.ndarray,
    task_source: tuple[str, EnvPart, EnvPart],
    robot_source: tuple[str, EnvPart, EnvPart],
    scenes: int,
    seed: int = 0,
    cache: str | None = None,
) -> np.ndarray:
    """The task module's anchors of a re-anchored stitch (``anchors@<fit>``): row j a task-X scene
    that means what the robot module's anchor j means to the robot source's task Y; each source
    given as (policy file, its robot, its task), their rollouts kept in ``cache``, if given.

    ``outcome``: the robot source rolled out from anchor j's scene ends at e_j; the task source's
    successful scene (of ``scenes`` rollouts, :func:`outcomes`) that ends nearest e_j. ``shuffled``:
    those rows permuted. ``both``: the candidate scenes matched by both sources' outcomes
    (:func:`match_anchors_by_both`); ``decoded``: decoded from those outcomes between the
    candidates (:func:`decode_anchors`). ``swapped``: anchor j with X's and Y's markers trading places."""
    anchors = np.asarray(anchors, np.float32)
    if fit == "swapped":
        return colour_swapped(anchors, robot_source[2], task_source[2])
    if fit not in ANCHOR_FITS:
        raise ValueError(f"unknown fit {fit!r}")
    mine = _source_outcomes(task_source[0], task_source[1].text, task_source[2].text, scenes, cache)

    def ends(source: tuple[str, EnvPart, EnvPart], scenes: np.ndarray) -> np.ndarray:
        return _source_anchor_ends(
            source[0],
            source[1].text,
            source[2].text,
            np.asarray(scenes, np.float32).tobytes(),
            scenes.shape[1],
            cache,
        )

    if fit in CROSSED_FITS:  # each scene described by where both sources end in it
        crossed = decode_anchors if fit == "decoded" else match_anchors_by_both
        return crossed(
            mine, ends(robot_source, mine.task_in), ends(robot_source, anchors), ends(task_source, anchors)
        )
    matched = match_anchors(mine, ends(robot_source, anchors))
    if fit == "shuffled":
        matched = matched[np.random.default_rng(seed).permutation(len(matched))]
    return matched
