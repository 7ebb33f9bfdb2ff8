"""Relative representation: cosine similarity of an embedding to embedded anchors (Moschella et al.)."""

from __future__ import annotations

from collections.abc import Callable

import torch
import torch.nn.functional as F
from torch import Tensor, nn


class RelativeProjection(nn.Module):
    """Maps ``x`` (..., task_dim) to cosine similarities (..., K) against K fixed anchor inputs.

    Choices (REFERENCE §3, §9):
    - The anchors are raw inputs (K x task_dim), stored as a persistent buffer, so they travel in
      the state_dict with the module; they are re-embedded by the *same* encoder on every forward
      pass. The encoder therefore applies its own input normalisation to the anchors too.
    - ``anchor_grad=True`` (default, as the authors): batch and anchors go through the encoder in
      one call, and gradients flow through the anchor embeddings.
      ``anchor_grad=False`` (as relreps): the anchors are embedded in a separate call under
      ``torch.no_grad()``. The encoder must not use batch statistics, so both give equal values.
    - Both embeddings are L2-normalised (``F.normalize``, eps 1e-12) before the inner product; no
      output normalisation, so values lie in [-1, 1] up to float rounding.
    """

    anchors: Tensor

    def __init__(self, anchors: Tensor, anchor_grad: bool = True) -> None:
        super().__init__()
        anchors = torch.as_tensor(anchors, dtype=torch.get_default_dtype())
        if anchors.ndim != 2 or anchors.shape[0] < 1:
            shape = tuple(anchors.shape)
            raise ValueError(f"anchors must be a non-empty (K, input_dim) matrix, got shape {shape}")
        self.register_buffer("anchors", anchors.detach().clone())
        self.anchor_grad = anchor_grad

    @property
    def num_anchors(self) -> int:
        return self.anchors.shape[0]

    def forward(self, encoder: Callable[[Tensor], Tensor], x: Tensor) -> Tensor:
        if x.shape[-1] != self.anchors.shape[-1]:
            in_dim, anchor_dim = x.shape[-1], self.anchors.shape[-1]
            raise ValueError(f"input last dim {in_dim} does not match anchor dim {anchor_dim}")
        lead, flat = x.shape[:-1], x.reshape(-1, x.shape[-1])
        anchors = self.anchors.to(flat.dtype)
        if self.anchor_grad:
            embedded = encoder(torch.cat([flat, anchors], 0))
            z_x, z_a = embedded[: flat.shape[0]], embedded[flat.shape[0] :]
        else:
            z_x = encoder(flat)
            with torch.no_grad():
                z_a = encoder(anchors)
        cos = F.normalize(z_x, dim=-1) @ F.normalize(z_a, dim=-1).T
        return cos.reshape(*lead, self.num_anchors)

    def extra_repr(self) -> str:
        return f"anchors={tuple(self.anchors.shape)}, anchor_grad={self.anchor_grad}"
