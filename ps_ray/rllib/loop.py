"""The one training loop: a :class:`TrainingRun` steps the RLlib algorithm, evaluates greedily,
applies the stopping rule and the after-training consolidation, and checkpoints; ``ps-ray train``
(:mod:`ps_ray.rllib.train`) and the sweep's Tune trial (:mod:`ps_ray.pipeline.training_trials`)
both drive it."""

from __future__ import annotations

import json
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from ps_ray.errors import UserError
from ps_ray.specs import reset_seeds
from ps_ray.specs.methods import spec_json
from ps_ray.specs.train import TrainSpec
from ps_ray.store import checkpoint
from ps_ray.store.run_layout import (
    ANCHORS_FILE,
    METRIC_FIELDS,
    POLICY_FILE,
    SIGNATURE_FILE,
    SPEC_FILE,
)


def make_env(spec: TrainSpec):
    """The env of a run: its robot and task, or the gymnasium env its ``env`` names."""
    if spec.env is not None:
        import gymnasium

        return gymnasium.make(spec.env)
    from ps_ray.envs import make

    return make(**spec.env_config)


def start_local_ray() -> None:
    """Ray for a run in this process (``ps-ray train``, ``ps-ray grid``), unless one runs: the
    cluster at ``RAY_ADDRESS`` when set (the run itself stays in this process), else a local
    instance with this machine's cores."""
    import os

    from ps_ray.rllib.ray_start import cluster_address, init_ray

    address = cluster_address()
    if address:
        init_ray(address)
    else:
        init_ray(num_cpus=max(1, os.cpu_count() or 1))


def prepare_anchors(spec: TrainSpec, run_dir: Path, given=None):
    """The anchor set of a PS run: the run folder's own (a resume), else the one its inputs give
    (:func:`read_inputs`: the init policy's or the anchors file's), else k-means over
    random-policy rollouts; saved into the run folder."""
    from ps_ray.data.anchor_file import load_anchor_set, save_anchor_set
    from ps_ray.data.anchors import AnchorSet, select_anchors
    from ps_ray.data.collect import collect_task_states

    path = run_dir / ANCHORS_FILE
    if path.exists():
        return load_anchor_set(path)
    if given is not None:
        anchor_set = given
    else:
        first = reset_seeds.fixed("anchors", spec.seed)  # the run's own anchor scenes
        states = collect_task_states(lambda: make_env(spec), episodes=spec.anchor_episodes, seed=first)
        anchor_set = AnchorSet.of(
            select_anchors(states, spec.interface_dim, seed=0),
            {
                "source": "random-policy rollouts",
                "env": spec.env_config,
                "episodes": spec.anchor_episodes,
                "num_states": int(len(states)),
            },
        )
    save_anchor_set(path, anchor_set)
    return anchor_set


@dataclass(frozen=True)
class Tick:
    """One turn of :meth:`TrainingRun.ticks`: the latest step's metrics, whether to save a
    checkpoint now, and (on the last tick only) the consolidation's figures."""

    row: dict[str, Any]
    checkpoint: bool
    finished: dict[str, float] | None = None


class TrainingRun:
    """One ModularSAC algorithm with its signature; the loop body shared by `ps-ray train` and Tune."""

    metric_fields: tuple[str, ...] = METRIC_FIELDS  # the columns of a step's row

    def __init__(
        self,
        spec: TrainSpec,
        anchor_set=None,
        *,
        threads: int = 1,
        gpu: float = 0,
        compile: bool = False,
        replay_store: Path | None = None,
    ):
        """``threads``: torch's CPU threads; ``gpu``: the learner's GPU share and ``compile`` its
        compiled forward pass (ps_ray.specs.resources);
        ``replay_store``: the folder of this run's replay segments, kept across checkpoints and
        attempts (:mod:`ps_ray.store.replay`; None: every checkpoint holds the whole buffer)."""
        from ps_ray.rllib.algo import algo_config
        from ps_ray.store.signature import Signature

        torch.set_num_threads(threads)
        anchors = None if anchor_set is None else anchor_set.anchors
        self.begin(spec, algo_config(spec, anchors, gpu=gpu, compile=compile).build_algo(), replay_store)
        self.signature = Signature(
            method=spec.method,
            settings=spec_json(spec.resolved),
            interface_dim=spec.interface_dim,
            hidden=spec.hidden,
            anchor_hash="" if anchor_set is None else anchor_set.hash,
            **self.algo.replay_dims,
        )
        if spec.init_policy is not None:
            self.algo.load_policy_weights(spec.init_policy)

    def begin(self, spec: TrainSpec, algo, replay_store: Path | None = None) -> None:
        """The loop's state at its start, for a source and a grid alike: ``spec`` sets its budget,
        stopping rule and consolidation (a grid's: every cell at once), ``algo`` is what it trains,
        ``replay_store`` where its replay segments are kept (None: whole in each checkpoint)."""
        self.spec, self.algo = spec, algo
        self.algo.replay_store = self.replay_store = replay_store
        self.start, self.start_steps = time.time(), 0
        self.streak = 0  # evaluations in a row at or above spec.target_success
        self.best: float | None = None  # the best greedy success so far (kept across resumes)
        self.consolidation = spec.resolved.consolidate
        self.consolidated: dict[str, float] = {}  # figures of the consolidation after the last step

    @property
    def env_steps(self) -> int:
        return self.algo.counters["env_steps"]

    @property
    def converged(self) -> bool:
        """The success target was met in ``target_evals`` evaluations in a row."""
        return self.spec.target_success is not None and self.streak >= self.spec.target_evals

    @property
    def done(self) -> bool:
        return self.converged or self.env_steps >= self.spec.env_steps

    def step(self) -> dict[str, Any]:
        self.consolidated = {}
        result = self.algo.train()
        ours = result.get("ps_ray", {})
        row = {k: ours.get(k) for k in self.metric_fields if k in ours}
        row.update(iteration=result["training_iteration"], wall_s=round(time.time() - self.start, 1))
        row.update(learner_figures(result))
        if row.get("eval_success") is not None:
            self.best = max(self.best if self.best is not None else -1.0, row["eval_success"])
            if self.spec.target_success is not None:
                self.streak = self.streak + 1 if row["eval_success"] >= self.spec.target_success else 0
        return {**row, **self.best_field()}

    def finish(self) -> dict[str, float]:
        """Once done: the method's consolidation (MethodSpec.consolidate), run once per finished
        run (a resumed finished run keeps it); its figures, prefixed ``consolidation_``."""
        if self.done and self.consolidation is not None and not self.consolidated:
            self.consolidated = self.algo.consolidate_actor(self.consolidation)
        return {f"consolidation_{k}": v for k, v in self.consolidated.items()}

    def ticks(self) -> Iterator[Tick]:
        """The one training loop, of ``ps-ray train`` and of the Tune trial: a step per tick until
        the run is done (budget or success target, decided by :meth:`step`), a checkpoint every
        ``checkpoint_every`` steps, then the method's consolidation (:meth:`finish`) and a last tick
        that repeats the last step's row with its figures, to be saved and finally evaluated."""
        row = self.position()  # a run restored already done takes no step
        while not self.done:
            row = self.step()
            yield Tick(row, checkpoint=not self.done and self.checkpoint_due(row))
        yield Tick(row, checkpoint=True, finished=self.finish())

    def checkpoint_due(self, row: dict[str, Any]) -> bool:
        """Whether the step of ``row`` ends with a checkpoint (every ``checkpoint_every`` steps)."""
        return row["iteration"] % self.spec.checkpoint_every == 0

    def position(self) -> dict[str, Any]:
        """Where the run stands without a step: iteration, env steps and the best so far."""
        return {"iteration": self.algo.iteration, "env_steps": self.env_steps, **self.best_field()}

    def best_field(self) -> dict[str, float]:
        """``best_eval_success`` once there has been an evaluation (before it, nothing)."""
        return {} if self.best is None else {"best_eval_success": self.best}

    def save(self, directory: Path) -> None:
        """RLlib checkpoint + replay buffer + policy.safetensors into `directory`."""
        import dataclasses

        self.algo.save_checkpoint(str(directory))
        signature = self.algo.export_policy(Path(directory) / POLICY_FILE, self.signature)
        (Path(directory) / SIGNATURE_FILE).write_text(json.dumps(dataclasses.asdict(signature), indent=2))
        (Path(directory) / SPEC_FILE).write_text(json.dumps(self.spec.to_dict(), indent=2))
        progress = {"streak": self.streak, "best": self.best, "consolidated": self.consolidated}
        (Path(directory) / checkpoint.PROGRESS_FILE).write_text(json.dumps(progress))
        checkpoint.seal(directory)

    def restore(self, directory: Path) -> None:
        """Resume from a checkpoint folder; CheckpointError (one line) if it is not a complete,
        unaltered ps_ray checkpoint. Nothing in it is unpickled."""
        self.algo.load_checkpoint(str(checkpoint.verify(directory, replay_store=self.replay_store)))
        self.start_steps = self.env_steps
        state = checkpoint.progress(directory)
        self.streak = int(state["streak"])
        self.best = None if state["best"] is None else float(state["best"])
        self.consolidated = {k: float(v) for k, v in state["consolidated"].items()}
        if self.consolidated and not self.done and self.spec.resolved.defer_relative:
            raise UserError(
                f"{directory}: this {self.spec.method} run finished at {self.env_steps} env steps "
                f"and switched its actor to the relative interface, so more training "
                f"(env_steps {self.spec.env_steps}) would not be its method's; start a new run"
            )

    def final_eval(self) -> dict[str, float]:
        """Greedy success and touching on twice the periodic evaluation's episodes, none of which
        the stopping rule read (an honest final figure, not the best of what stopped it)."""
        return self.algo.evaluate_greedy(self.spec.eval_episodes * 2, final=True)

    def stop(self) -> None:
        self.algo.stop()

    def progress_line(self, row: dict[str, Any]) -> str:
        rate = (self.env_steps - self.start_steps) / max(time.time() - self.start, 1e-9)
        return (
            f"[{self.spec.label()}] {row['env_steps']:>7}/{self.spec.env_steps} steps "
            f"{row['updates']:>7} updates  train success {row.get('train_success') or 0:.2f}  "
            f"eval success {row['eval_success']:.2f} touching {format_figure(row.get('eval_touching'))}"
            f"  {rate:.0f} steps/s"
        )


def read_inputs(spec: TrainSpec):
    """Read and check the files a run starts from, before anything is written: the policy of
    ``init_policy`` must fit the spec's method, sizes and env; ``anchors`` must give an anchor
    set of K = interface_dim. Returns the anchor set they give (None: none given)."""
    if spec.init_policy is not None:
        from ps_ray.nets.policy_file import load_policy, policy_anchor_set
        from ps_ray.stitching.rule import start_problems

        _, signature = load_policy(spec.init_policy)  # every tensor read and checked
        problems = start_problems(spec, signature)
        if problems:
            raise UserError(f"{spec.init_policy}: cannot start this run: " + "; ".join(problems))
        return policy_anchor_set(spec.init_policy) if spec.resolved.uses_anchors else None
    if spec.anchors is not None and spec.resolved.uses_anchors:
        from ps_ray.data.anchor_file import anchors_from_file

        return anchors_from_file(spec.anchors, spec.interface_dim, seed=0)
    return None


# The learner's figures a trial's result rows carry (Tune and MLflow; metrics.csv keeps its columns):
# the entropy temperature and the policy's entropy, mean over the step's updates.
LEARNER_FIGURES = ("alpha", "entropy")


def learner_figures(result: dict[str, Any]) -> dict[str, float]:
    """:data:`LEARNER_FIGURES` of an RLlib result (none before the first update; a grid: its
    modules' mean)."""
    from ray.rllib.utils.metrics import LEARNER_RESULTS

    modules = [m for m in result.get(LEARNER_RESULTS, {}).values() if isinstance(m, dict)]
    out = {}
    for key in LEARNER_FIGURES:
        values = [float(np.mean(m[key])) for m in modules if key in m]
        if values:
            out[key] = float(np.mean(values))
    return out


def format_figure(x: float | None) -> str:
    return "n/a" if x is None or np.isnan(x) else f"{x:.2f}"
