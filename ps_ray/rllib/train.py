"""`ps-ray train`: one policy trained (or resumed) into a run folder, through the one training
loop (:mod:`ps_ray.rllib.loop`): progress on the terminal, greedy evaluations, checkpoints.

A run directory holds:
  spec.json          the TrainSpec (a directory belongs to one spec; a different one is refused)
  anchors.npz        the anchor set (PS only)
  checkpoint/        the latest checkpoint (ps_ray/store/checkpoint.py: safetensors, npz, JSON, sealed
                     by a manifest; replaced atomically)
  policy.safetensors actor, critics and targets with the interface signature
  best_policy.safetensors  the same at the best greedy evaluation so far
  metrics.csv        one row per training step
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from ps_ray.errors import UserError
from ps_ray.rllib.loop import TrainingRun, format_figure, prepare_anchors, read_inputs, start_local_ray
from ps_ray.rllib.run_loop import train_to_folder
from ps_ray.specs.train import TrainSpec, require_same
from ps_ray.store.atomic import write_text
from ps_ray.store.layout import LOG_FOLDER
from ps_ray.store.lock import folder_lock
from ps_ray.store.run_folder import best_so_far, latest_checkpoint
from ps_ray.store.run_layout import (
    BEST_POLICY_FILE,
    METRIC_FIELDS,
    POLICY_FILE,
    REPLAY_FOLDER,
    RESULT_FILE,
    SPEC_FILE,
)
from ps_ray.store.terminal import others_to


def train(
    spec: TrainSpec, run_dir: str | Path, *, progress: bool = True, compile: bool = False
) -> dict[str, Any]:
    """Train (or resume) until spec.env_steps; returns the last metrics row with final_* figures.
    One process at a time per run folder (:mod:`ps_ray.store.lock`). ``compile``: see TrainingRun."""
    run_dir = Path(run_dir).resolve()  # RLlib's checkpoint writer needs absolute paths
    _check_run_dir(spec, run_dir)
    given = read_inputs(spec)  # a bad --init-policy or --anchors fails before the folder is made
    with folder_lock(run_dir, "run"):
        return _train(spec, run_dir, given, progress, compile)


def _check_run_dir(spec: TrainSpec, run_dir: Path) -> None:
    """A run directory belongs to one policy; only the budget and reporting settings may change."""
    spec_file = run_dir / SPEC_FILE
    if spec_file.exists():
        try:
            data = json.loads(spec_file.read_text())
        except (UnicodeDecodeError, json.JSONDecodeError) as e:
            raise UserError(f"{spec_file}: not a ps_ray run spec (not JSON text: {e})") from None
        if not isinstance(data, dict):
            raise UserError(f"{spec_file}: not a ps_ray run spec (a JSON {type(data).__name__})")
        stored = TrainSpec.from_mapping(TrainSpec.upgrade(data), where=str(spec_file)).identity()
        require_same(
            stored, spec.identity(), f"{run_dir} holds a run of another spec", "use another --run-dir"
        )


def _train(spec: TrainSpec, run_dir: Path, given, progress: bool, compile: bool) -> dict[str, Any]:
    anchor_set = prepare_anchors(spec, run_dir, given) if spec.resolved.uses_anchors else None
    with others_to(run_dir / LOG_FOLDER / "ray.log"):  # Ray's and RLlib's start-up messages
        start_local_ray()
        run = TrainingRun(spec, anchor_set, compile=compile, replay_store=run_dir / REPLAY_FOLDER)  # loads
    _check_run_dir(spec, run_dir)  # --init-policy: a bad one fails before spec.json
    resume_from = latest_checkpoint(run_dir)
    if resume_from is not None:
        run.restore(resume_from)  # may refuse the new budget: spec.json is written after it
        if progress:
            print(f"[{spec.label()}] resumed at {run.env_steps} env steps", flush=True)
    write_text(run_dir / SPEC_FILE, json.dumps(spec.to_dict(), indent=2))
    best_file = best_so_far(run_dir)  # the best policy file may be newer than the checkpoint
    if best_file >= 0:
        run.best = max(best_file, run.best if run.best is not None else best_file)
    best_before = [run.best]

    def on_row(row: dict[str, Any]) -> None:
        if row.get("eval_success") is None:
            return
        if best_before[0] is None or row["eval_success"] > best_before[0]:  # a new best greedy policy
            run.algo.export_policy(
                run_dir / BEST_POLICY_FILE,
                run.signature,
                extra={"eval_success": repr(run.best), "env_steps": str(row["env_steps"])},
            )
        best_before[0] = run.best
        if progress:
            print(run.progress_line(row), flush=True)

    row, final = train_to_folder(run, run_dir, METRIC_FIELDS, on_row=on_row)
    write_text(run_dir / RESULT_FILE, json.dumps(row, indent=2))
    run.stop()
    if progress:
        print(
            f"[{spec.label()}] done: final greedy success {final['success']:.2f}, touching "
            f"{format_figure(final['touching'])}; policy in {run_dir / POLICY_FILE}",
            flush=True,
        )
    return row
