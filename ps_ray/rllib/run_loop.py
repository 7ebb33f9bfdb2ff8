"""The run-folder loop that `ps-ray train` and `ps-ray grid` share: a :class:`TrainingRun`'s ticks
appended to ``metrics.csv``, checkpoints swapped in atomically when a tick asks, then a last
checkpoint and the final evaluation. What differs between the two (the best policy file of a
source, the cells' files of a grid) is the caller's."""

from __future__ import annotations

import csv
from collections.abc import Callable
from pathlib import Path
from typing import Any

from ps_ray.rllib.loop import TrainingRun
from ps_ray.store.run_folder import metrics_up_to, save_atomically
from ps_ray.store.run_layout import METRICS_FILE


def train_to_folder(
    run: TrainingRun,
    run_dir: Path,
    fields: tuple[str, ...],
    *,
    copy_out: dict[str, str] | None = None,
    on_row: Callable[[dict[str, Any]], None] | None = None,
) -> tuple[dict[str, Any], dict[str, Any]]:
    """Train ``run`` to its budget in ``run_dir``: rows after the checkpoint it resumed from are
    dropped first, each tick's row is appended (columns ``fields``) and handed to ``on_row``, a
    checkpoint is saved when the tick asks (``copy_out``: files copied out of it,
    :func:`ps_ray.store.run_folder.save_atomically`), and once more at the end. Returns the result
    (the last row, the stopping figures, ``final_*``, the best evaluation, ``converged``) and the
    final evaluation; writing them and stopping the run are the caller's."""
    metrics_up_to(run_dir, run.env_steps, fields)
    with open(run_dir / METRICS_FILE, "a", newline="") as f:
        writer = csv.DictWriter(f, fields, extrasaction="ignore")
        if f.tell() == 0:
            writer.writeheader()
        for tick in run.ticks():
            if tick.finished is not None:
                break
            writer.writerow(tick.row)
            if tick.checkpoint:
                f.flush()
                save_atomically(run.save, run_dir, copy_out)
            if on_row is not None:
                on_row(tick.row)
    save_atomically(run.save, run_dir, copy_out)
    final = run.final_eval()
    result = {
        **tick.row,
        **tick.finished,
        **{f"final_{k}": v for k, v in final.items()},
        **run.best_field(),
        "converged": run.converged,
    }
    return result, final
