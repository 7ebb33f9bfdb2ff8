"""What each stage's Tune trials ask Ray for, and what a trial does with what it was granted.

A sweep's ``resources:`` block (docs/cluster.md) gives each stage its CPUs and GPU share per trial:

```yaml
resources:
  train: {cpu: 2, gpu: 0.25}   # four training trials share a GPU; torch uses 2 threads each
  zero_shot: {cpu: 1}          # evaluation steps PyBullet on the CPU
```

The learner of a training trial runs on the GPU share it was granted (RLlib's
``num_gpus_per_learner``); env stepping, evaluation, stitching and analysis stay on the CPU, and
policy files and checkpoints are written as CPU tensors, so a GPU-trained run resumes and
stitches on a laptop. Resources do not change what a stage computes, so they are not part of a
sweep's training identity: a sweep resumed on other hardware keeps its trials.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from ps_ray.errors import UserError
from ps_ray.specs.stages import STAGES_WITH_TRIALS


@dataclass(frozen=True)
class StageResources:
    """One trial's request: ``cpu`` cores (torch threads follow them) and a ``gpu`` share; and
    ``compile``: the learner's forward pass compiled (RLlib's ``torch_compile_learner``), off by
    default because it measured slower on CPU cores (docs/cost.md)."""

    cpu: float = 1
    gpu: float = 0
    compile: bool = False

    def __post_init__(self) -> None:
        for name, low in (("cpu", 0), ("gpu", 0)):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
                raise UserError(f"resources {name} must be a number, got {value!r}")
            if value < low or (name == "cpu" and value == 0):
                raise UserError(
                    f"resources {name} must be {'positive' if name == 'cpu' else '>= 0'}, got {value}"
                )
        if not isinstance(self.compile, bool):
            raise UserError(f"resources compile must be true or false, got {self.compile!r}")
        if self.gpu > 1 and not float(self.gpu).is_integer():
            raise UserError(f"resources gpu above 1 must be a whole number of GPUs, got {self.gpu}")

    def tune_request(self) -> dict[str, float]:
        return {"cpu": self.cpu, **({"gpu": self.gpu} if self.gpu else {})}

    @property
    def threads(self) -> int:
        return max(1, int(self.cpu))


@dataclass(frozen=True)
class ResourcesSpec:
    """Each stage's per-trial request (default: one CPU, no GPU)."""

    train: StageResources = StageResources()
    grid: StageResources = StageResources()
    zero_shot: StageResources = StageResources()
    few_shot: StageResources = StageResources()

    def __post_init__(self) -> None:
        for stage in STAGES_WITH_TRIALS:
            value = getattr(self, stage)
            if isinstance(value, dict):
                unknown = [k for k in value if k not in ("cpu", "gpu", "compile")]
                if unknown:
                    raise UserError(
                        f"resources.{stage}: unknown key {unknown[0]!r}; valid keys: cpu, gpu, compile"
                    )
                try:
                    object.__setattr__(self, stage, StageResources(**value))
                except UserError as e:
                    raise UserError(f"resources.{stage}: {e}") from None
            elif not isinstance(value, StageResources):
                raise UserError(
                    f"resources.{stage}: expected a mapping like {{cpu: 1, gpu: 0}}, got {value!r}"
                )


def device_tags(resources: StageResources) -> dict[str, str]:
    """MLflow tags of a stage's runs: the device its trials asked for (a GPU share that finds no
    CUDA stops the trial, :func:`learner_device`), their CPUs and GPU share (docs/cluster.md)."""
    return {
        "ps_ray.device": "cuda" if resources.gpu else "cpu",
        "ps_ray.cpus": f"{resources.cpu:g}",
        "ps_ray.gpu_share": f"{resources.gpu:g}",
    }


def learner_device(gpu: float) -> str:
    """The torch device a learner granted ``gpu`` uses: ``"cpu"`` for none, ``"cuda"`` where CUDA
    is there; a GPU share on a node without CUDA is one clear error, never a silent CPU run."""
    if not gpu:
        return "cpu"
    import torch

    if not torch.cuda.is_available():
        raise UserError(
            f"resources: a trial was granted gpu {gpu} but torch sees no CUDA device on this node "
            f"(torch {torch.__version__}, CUDA build {torch.version.cuda}); install a CUDA torch "
            f"there or set the stage's gpu to 0"
        )
    return "cuda"
