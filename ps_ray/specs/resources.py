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

from typing import Annotated, Any

from pydantic import AfterValidator, Field

from ps_ray.errors import UserError
from ps_ray.specs.engine import Invalid, Number, finite, spec, sub_spec


@spec("resources")
class StageResources:
    """One trial's request: ``cpu`` cores (torch threads follow them) and a ``gpu`` share; and
    ``compile``: the learner's forward pass compiled (RLlib's ``torch_compile_learner``), off by
    default because it measured slower on CPU cores (docs/cost.md)."""

    cpu: Annotated[Number, Field(gt=0), AfterValidator(finite)] = 1
    gpu: Annotated[Number, Field(ge=0), AfterValidator(finite)] = 0
    compile: bool = False

    def __post_init__(self) -> None:
        if self.gpu > 1 and not float(self.gpu).is_integer():
            raise Invalid(f"gpu above 1 must be a whole number of GPUs, got {self.gpu}")

    def tune_request(self) -> dict[str, float]:
        return {"cpu": self.cpu, **({"gpu": self.gpu} if self.gpu else {})}

    @property
    def threads(self) -> int:
        return max(1, int(self.cpu))


def _stage(stage: str) -> Any:
    return Annotated[StageResources, sub_spec(StageResources, f"resources.{stage}")]


@spec("resources")
class ResourcesSpec:
    """Each stage's per-trial request (default: one CPU, no GPU)."""

    train: _stage("train") = StageResources()
    grid: _stage("grid") = StageResources()
    zero_shot: _stage("zero_shot") = StageResources()
    few_shot: _stage("few_shot") = StageResources()


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
