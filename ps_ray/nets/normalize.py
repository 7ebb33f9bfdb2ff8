"""Running mean/std input normalisation (replaces the authors' BatchNorm1d; see docs/authors_code.md §0)."""

from __future__ import annotations

import torch
from torch import Tensor, nn


class RunningNorm(nn.Module):
    """``clamp((x - mean) / max(std, eps), -clip, clip)`` with statistics in buffers, never trained.

    The statistics change only through :meth:`update` (parallel Welford / Chan et al. merge of a
    batch into the running count, mean and population variance, merged in float64 and stored in
    float32: RLlib's checkpoints turn float64 state into float32, which must lose nothing), never
    in ``forward``, so train/eval mode does not matter and target copies can share them by
    ``load_state_dict``. Before the first update (count 0, mean 0, var 1) it only clips.
    """

    count: Tensor
    mean: Tensor
    var: Tensor

    def __init__(self, dim: int, clip: float = 5.0, eps: float = 1e-2) -> None:
        super().__init__()
        if dim < 1:
            raise ValueError(f"RunningNorm needs dim >= 1, got {dim}")
        self.dim, self.clip, self.eps = dim, clip, eps
        self.register_buffer("count", torch.zeros(()))
        self.register_buffer("mean", torch.zeros(dim))
        self.register_buffer("var", torch.ones(dim))

    @torch.no_grad()
    def update(self, x: Tensor) -> None:
        """Merge a batch of shape (..., dim) into the running statistics."""
        if x.shape[-1] != self.dim:
            raise ValueError(f"RunningNorm({self.dim}) got input with last dim {x.shape[-1]}")
        # on the statistics' device, whatever the data's (a CPU batch into GPU buffers)
        batch = x.detach().reshape(-1, self.dim).to(device=self.mean.device, dtype=torch.float64)
        n_b = batch.shape[0]
        if n_b == 0:
            return
        mean_b = batch.mean(0)
        var_b = batch.var(0, unbiased=False)
        n_a = self.count.double()
        n = n_a + n_b
        delta = mean_b - self.mean.double()
        mean = self.mean.double() + delta * (n_b / n)
        m2 = self.var.double() * n_a + var_b * n_b + delta.square() * (n_a * n_b / n)
        self.mean.copy_(mean)
        self.var.copy_(m2 / n)
        self.count.copy_(n)

    def forward(self, x: Tensor) -> Tensor:
        std = self.var.sqrt().clamp_min(self.eps)
        return ((x - self.mean) / std).clamp(-self.clip, self.clip)

    def extra_repr(self) -> str:
        return f"{self.dim}, clip={self.clip}, eps={self.eps}"
