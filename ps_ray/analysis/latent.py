"""The module interface: dumps on fixed probe states, pairwise distances, PCA.

Interface of a trained actor's task module on task states S (the paper's appendix): the relative
vector (cosine similarities to the K anchor embeddings) for PS, the raw latent for the other
modular methods. Plain has no task-only interface (its bottom half also sees the robot state) and
is left out.

Average pairwise distances between two modules g1, g2 over the same probe states (appendix eqs.):
    d_cos = mean_i (1 - cos(g1(s_i), g2(s_i))),   d_L2 = mean_i ||g1(s_i) - g2(s_i)||.
Compared groups: modules that differ only in seed ("seeds") or only in robot ("robots").
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from itertools import combinations
from pathlib import Path

import numpy as np
import pandas as pd

from ps_ray.errors import UserError
from ps_ray.specs.names import EnvPart

QUADRANTS = ("q1", "q2", "q3", "q4")  # goal x/y signs (+,+), (-,+), (-,-), (+,-), as reach regions
COMPARISONS = {"seeds": "seed", "robots": "robot"}  # comparison -> the field that varies


# -- probe states -----------------------------------------------------------------------------------
@dataclass(frozen=True)
class Probes:
    """Fixed task-module inputs and the goal quadrant of each (the colour of the plots)."""

    states: np.ndarray  # (N, task_dim) float32
    labels: np.ndarray  # (N,) str, one of QUADRANTS


def probe_states(task: EnvPart, per_group: int = 250, seed: int = 0) -> Probes:
    """Task inputs at reset of the real env, ``per_group`` per goal quadrant.

    Reach (any goal region): goals drawn in each of the four quadrant discs (the paper's four
    directions), whatever the task's own goal region is, so a reach half is probed outside its
    half too. Other tasks: resets of the task itself, labelled by the quadrant of the point to
    reach (for markers: the named marker), until every quadrant has ``per_group`` states."""
    from ps_ray.envs import make
    from ps_ray.envs.goals import task_input
    from ps_ray.envs.tasks import resolve_task

    task, states, labels = EnvPart(task), [], []
    if hasattr(resolve_task(task).options, "goal_region"):  # a task whose goals can be placed
        for index, quadrant in enumerate(QUADRANTS):
            env = make("panda", {**task, "goal_region": quadrant})
            for i in range(per_group):
                obs, _ = env.reset(seed=seed + index * per_group + i)
                states.append(task_input(obs))
                labels.append(quadrant)
            env.close()
    else:
        env = make("panda", task)
        counts = dict.fromkeys(QUADRANTS, 0)
        for i in range(200 * per_group):
            if min(counts.values()) >= per_group:
                break
            obs, _ = env.reset(seed=seed + i)
            quadrant = goal_quadrant(env.task.target_position)  # where the goal is in the world
            if counts[quadrant] < per_group:
                counts[quadrant] += 1
                states.append(task_input(obs))
                labels.append(quadrant)
        env.close()
    order = np.argsort(np.asarray(labels), kind="stable")
    return Probes(np.asarray(states, np.float32)[order], np.asarray(labels)[order])


def goal_quadrant(goal: np.ndarray) -> str:
    x, y = float(goal[0]), float(goal[1])
    return {(True, True): "q1", (False, True): "q2", (False, False): "q3", (True, False): "q4"}[
        (x >= 0, y >= 0)
    ]


# -- interface dumps --------------------------------------------------------------------------------
def interface_of(policy_path: str | Path, states: np.ndarray) -> np.ndarray:
    """The actor task module's interface on ``states`` (N, K) for a modular policy file."""
    import torch

    from ps_ray.nets.policy_file import load_policy

    nets, signature = load_policy(policy_path)
    if not signature.spec.modular:
        raise UserError(f"{policy_path}: method {signature.method!r} has no task-only interface")
    with torch.no_grad():
        return nets.actor.interface(torch.as_tensor(states), None).numpy()


@dataclass(frozen=True)
class Dump:
    """One module's interface on the probe states of its task."""

    key: str  # trial key
    method: str
    robot: str
    task: str
    seed: int
    interface_dim: int
    values: np.ndarray  # (N, K)


def dump_interfaces(entries: Iterable, probes_for: Callable[[EnvPart], Probes]) -> list[Dump]:
    """Dumps of every modular zoo entry; ``probes_for(task)`` gives the probe states of a task."""
    from ps_ray.specs.methods import method_spec

    dumps = []
    for entry in entries:
        if not method_spec(entry.key.method).modular:
            continue
        probes = probes_for(entry.task)
        k = entry.key
        dumps.append(
            Dump(
                str(k),
                k.method,
                k.robot,
                k.task,
                k.seed,
                k.interface_dim,
                interface_of(entry.path, probes.states),
            )
        )
    return dumps


# -- distances --------------------------------------------------------------------------------------
def cosine_distance(a: np.ndarray, b: np.ndarray) -> float:
    """Mean over rows of 1 - cos(a_i, b_i) (0 for identical directions, up to 2)."""
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    _check_pair(a, b)
    cos = (a * b).sum(-1) / np.maximum(np.linalg.norm(a, axis=-1) * np.linalg.norm(b, axis=-1), 1e-12)
    return float(np.mean(1.0 - cos))


def l2_distance(a: np.ndarray, b: np.ndarray) -> float:
    """Mean over rows of ||a_i - b_i||."""
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    _check_pair(a, b)
    return float(np.mean(np.linalg.norm(a - b, axis=-1)))


DISTANCES: dict[str, Callable[[np.ndarray, np.ndarray], float]] = {
    "cosine": cosine_distance,
    "l2": l2_distance,
}


def _check_pair(a: np.ndarray, b: np.ndarray) -> None:
    if a.shape != b.shape or a.ndim != 2:
        raise ValueError(f"interfaces must be (N, K) arrays of one shape, got {a.shape} and {b.shape}")


def distance_matrix(named: Mapping[str, np.ndarray], metric: str) -> pd.DataFrame:
    """Square, symmetric matrix of the average pairwise ``metric`` distance between named dumps."""
    fn = DISTANCES[metric]
    names = list(named)
    out = pd.DataFrame(0.0, index=names, columns=names)
    for x, y in combinations(names, 2):
        out.loc[x, y] = out.loc[y, x] = fn(named[x], named[y])
    return out


@dataclass(frozen=True)
class Group:
    """Modules of one method and interface dim that differ only in the compared field."""

    comparison: str  # "seeds" or "robots"
    method: str
    interface_dim: int
    fixed: str  # what the members share, e.g. "panda, reach" or "reach, seed 101"
    members: dict[str, Dump]  # compared value (seed or robot) -> dump

    def matrix(self, metric: str) -> pd.DataFrame:
        return distance_matrix({name: d.values for name, d in self.members.items()}, metric)


def groups(dumps: Iterable[Dump], comparison: str) -> list[Group]:
    """Groups of two or more modules that differ only in ``COMPARISONS[comparison]``."""
    varying = COMPARISONS[comparison]
    fixed_fields = [f for f in ("method", "interface_dim", "robot", "task", "seed") if f != varying]
    buckets: dict[tuple, dict[str, Dump]] = {}
    for dump in sorted(dumps, key=lambda d: d.key):
        fixed = tuple(getattr(dump, f) for f in fixed_fields)
        buckets.setdefault(fixed, {})[str(getattr(dump, varying))] = dump
    out = []
    for fixed, members in buckets.items():
        if len(members) < 2:
            continue
        values = dict(zip(fixed_fields, fixed))
        shared = [
            values[f] if f != "seed" else f"seed {values[f]}"
            for f in ("robot", "task", "seed")
            if f != varying
        ]
        out.append(Group(comparison, values["method"], values["interface_dim"], ", ".join(shared), members))
    return out


def pair_cells(all_groups: Iterable[Group]) -> pd.DataFrame:
    """One row per compared pair of modules: the paper's distances and the retrieval scores.
    ``cluster`` is what the pair's group holds fixed ("robot, task" across seeds, "task, seed"
    across robots): the unit the confidence intervals resample."""
    from ps_ray.analysis.alignment import retrieval

    records = []
    for group in all_groups:
        for x, y in combinations(list(group.members), 2):
            a, b = group.members[x].values, group.members[y].values
            records.append(
                {
                    "comparison": group.comparison,
                    "interface_dim": group.interface_dim,
                    "method": group.method,
                    "cluster": group.fixed,
                    "a": x,
                    "b": y,
                    **{m: fn(a, b) for m, fn in DISTANCES.items()},
                    **retrieval(a, b),
                }
            )
    columns = ["comparison", "interface_dim", "method", "cluster", "a", "b", *DISTANCES, "mrr", "top1"]
    return pd.DataFrame(records, columns=columns)


ALIGNMENT_METRICS = (*DISTANCES, "mrr", "top1")


def distance_table(all_groups: Iterable[Group]) -> pd.DataFrame:
    """Per (comparison, interface dim, method): mean and std over the distinct pairs of every
    group (the paper's appendix tables: cosine and L2), the same for the retrieval MRR and top-1,
    and 95% CIs of the means resampling the groups' fixed parts (:mod:`ps_ray.analysis.stats`)."""
    from ps_ray.analysis.stats import estimate

    cells = pair_cells(all_groups)
    records = []
    for (c, d, m), part in cells.groupby(["comparison", "interface_dim", "method"], sort=True):
        row = {"comparison": c, "interface_dim": d, "method": m, "pairs": len(part)}
        for metric in ALIGNMENT_METRICS:
            values = part[metric].to_numpy()
            e = estimate(values, part["cluster"].to_numpy())
            row.update(
                {
                    f"{metric}_mean": e.mean,
                    f"{metric}_std": float(np.std(values)),
                    f"{metric}_lo": e.mean_lo,
                    f"{metric}_hi": e.mean_hi,
                }
            )
        records.append(row)
    columns = [
        "comparison",
        "interface_dim",
        "method",
        "pairs",
        *(f"{m}_{s}" for m in ALIGNMENT_METRICS for s in ("mean", "std", "lo", "hi")),
    ]
    return pd.DataFrame(records, columns=columns)


def spread_table(dumps: Iterable[Dump]) -> pd.DataFrame:
    """Within-network spread of every dump and whether it is flagged as collapsed."""
    from ps_ray.analysis.alignment import collapsed, spread

    return pd.DataFrame(
        [
            {
                "key": d.key,
                "method": d.method,
                "interface_dim": d.interface_dim,
                "spread": spread(d.values),
                "collapsed": collapsed(d.values),
            }
            for d in dumps
        ],
        columns=["key", "method", "interface_dim", "spread", "collapsed"],
    )


def mean_matrix(all_groups: Iterable[Group], metric: str) -> pd.DataFrame:
    """The element-wise mean of groups' matrices over the labels they share (for one heatmap)."""
    frames = [g.matrix(metric) for g in all_groups]
    return pd.concat(frames).groupby(level=0, sort=False).mean().loc[frames[0].index, frames[0].columns]


# -- PCA ----------------------------------------------------------------------------------------------
def shared_pca(values: list[np.ndarray], components: int = 2) -> list[np.ndarray]:
    """Project every dump on one PCA basis fitted to all of them together, so that aligned
    interfaces land on the same points (a separate PCA per network may flip or rotate axes)."""
    from sklearn.decomposition import PCA

    pca = PCA(n_components=components, random_state=0).fit(np.concatenate(values))
    return [pca.transform(v) for v in values]


def save_dumps(path: Path, probes: Mapping[str, Probes], dumps: Iterable[Dump]) -> None:
    """Interface dumps and the probe states as safetensors (no pickle); metadata names each dump."""
    import json

    from safetensors.numpy import save_file

    tensors, meta = {}, {}
    for task, p in probes.items():
        tensors[f"probes/{task}"] = np.ascontiguousarray(p.states)
        meta[f"probes/{task}"] = json.dumps(p.labels.tolist())
    for d in dumps:
        tensors[f"interface/{d.key}"] = np.ascontiguousarray(d.values, np.float32)
    path.parent.mkdir(parents=True, exist_ok=True)
    save_file(tensors, str(path), metadata={"labels": json.dumps(meta)})
