"""Relative representation: cosine similarity of an embedding to embedded anchors (Moschella et al.).

The paper's projection and its variants (docs/methods.md) are settings of one
:class:`ps_ray.specs.methods.RelativeSpec`, a field of a method's :class:`ps_ray.specs.methods.MethodSpec`.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from ps_ray.specs.methods import RelativeSpec

SCALE_EPS = 1e-6
REF_STD_FLOOR = 1e-2  # task inputs are metres, radians and their rates: 1 cm is "no spread"


PAPER = RelativeSpec()  # the authors' projection: cosine only, gradients through the anchors


def input_reference(x: Tensor, anchors: Tensor, bandwidth: float = 1.0) -> Tensor:
    """The reference interface of raw task inputs x (B x task_dim) against K anchors: Gaussian
    kernel similarities exp(-d^2 / 2 s^2) in the space standardised by the anchors' per-dimension
    mean and std (std floored at REF_STD_FLOOR), with s^2 = ``bandwidth`` x the median squared
    distance between anchors. A fixed function of the anchors: no parameters, no data statistics."""
    mean, std = anchors.mean(0), anchors.std(0, unbiased=False).clamp_min(REF_STD_FLOOR)
    a, x = (anchors - mean) / std, (x - mean) / std
    width = bandwidth * torch.cdist(a, a).pow(2).median().clamp_min(SCALE_EPS)
    return torch.exp(-torch.cdist(x, a).pow(2) / (2 * width))


class AnchorReference(NamedTuple):
    """What a projection needs from the anchors: centring statistics (or None) and the unit
    anchor directions (K x D). Fixed weights give a fixed reference, so evaluation computes it once."""

    mean: Tensor | None
    std: Tensor | None
    directions: Tensor


class RelativeProjection(nn.Module):
    """Maps ``x`` (..., task_dim) to similarities (..., K) against K fixed anchor inputs.

    The anchors are raw inputs (K x task_dim) in a persistent buffer, so they travel in the
    state_dict; they are re-embedded by the *same* encoder (its input normalisation included) on
    every forward pass. Both embeddings are L2-normalised (eps 1e-12) before the inner product, so
    without ``norm`` and ``scale`` the values lie in [-1, 1].
    """

    anchors: Tensor

    def __init__(self, anchors: Tensor, spec: RelativeSpec = PAPER) -> None:
        super().__init__()
        anchors = torch.as_tensor(anchors, dtype=torch.get_default_dtype())
        if anchors.ndim != 2 or anchors.shape[0] < 1:
            shape = tuple(anchors.shape)
            raise ValueError(f"anchors must be a non-empty (K, input_dim) matrix, got shape {shape}")
        if spec.center != "none" and anchors.shape[0] < 2:
            raise ValueError("centring by anchor statistics needs at least 2 anchors")
        self.register_buffer("anchors", anchors.detach().clone())
        self.spec = spec

    @property
    def num_anchors(self) -> int:
        return self.anchors.shape[0]

    @property
    def penalizes(self) -> bool:
        """Whether the spec adds penalties to the training loss (norm_reg or ref_weight)."""
        return bool(self.spec.norm_reg or self.spec.ref_weight)

    @property
    def anchor_grad(self) -> bool:
        return self.spec.anchor_grad

    def reference(self, anchor_z: Tensor) -> AnchorReference:
        """The anchor side of the projection from the anchors' embeddings (K x D)."""
        mean = std = None
        if self.spec.center != "none":
            mean = anchor_z.mean(0)
            anchor_z = anchor_z - mean
        if self.spec.center == "standard":
            std = anchor_z.std(0, unbiased=False) + SCALE_EPS
            anchor_z = anchor_z / std
        return AnchorReference(mean, std, F.normalize(anchor_z, dim=-1))

    def project(self, z: Tensor, ref: AnchorReference) -> Tensor:
        """Embeddings (B x D) -> relative vectors (B x K) against a reference."""
        if ref.mean is not None:
            z = z - ref.mean
        if ref.std is not None:
            z = z / ref.std
        return self._post(F.normalize(z, dim=-1) @ ref.directions.T)

    def _post(self, rel: Tensor) -> Tensor:
        if self.spec.norm == "layer":
            rel = F.layer_norm(rel, rel.shape[-1:])
        return rel * self.spec.scale if self.spec.scale != 1.0 else rel

    def _flatten(self, x: Tensor) -> tuple[Tensor, Tensor]:
        """x (..., task_dim) as rows (N x task_dim), and the anchors in its dtype."""
        if x.shape[-1] != self.anchors.shape[-1]:
            in_dim, anchor_dim = x.shape[-1], self.anchors.shape[-1]
            raise ValueError(f"input last dim {in_dim} does not match anchor dim {anchor_dim}")
        flat = x.reshape(-1, x.shape[-1])
        return flat, self.anchors.to(flat.dtype)

    def forward(self, encoder: Callable[[Tensor], Tensor], x: Tensor) -> Tensor:
        flat, anchors = self._flatten(x)
        if self.spec.anchor_grad:
            embedded = encoder(torch.cat([flat, anchors], 0))
            z_x, z_a = embedded[: flat.shape[0]], embedded[flat.shape[0] :]
        else:
            z_x = encoder(flat)
            with torch.no_grad():
                z_a = encoder(anchors)
        return self.project(z_x, self.reference(z_a)).reshape(*x.shape[:-1], self.num_anchors)

    def penalized(self, encoder: Callable[[Tensor], Tensor], x: Tensor) -> tuple[Tensor, Tensor]:
        """``forward(encoder, x)`` and ``penalty(encoder, x)`` from one pass of the encoder over the
        states and the anchors: the training step's path, which needs both."""
        if not self.penalizes:
            return self(encoder, x), x.new_zeros(())
        flat, anchors = self._flatten(x)
        inputs = torch.cat([flat, anchors], 0)
        z = encoder(inputs)
        z_anchors = z[flat.shape[0] :]
        ref = self.reference(z_anchors if self.spec.anchor_grad else z_anchors.detach())
        relative = self.project(z, ref)
        interface = relative[: flat.shape[0]].reshape(*x.shape[:-1], self.num_anchors)
        return interface, self._penalty(z, relative, inputs, anchors)

    def penalty(self, encoder: Callable[[Tensor], Tensor], x: Tensor) -> Tensor:
        """The spec's penalties on the states ``x`` and the anchors (a scalar; zero when neither
        ``norm_reg`` nor ``ref_weight`` is set): ``norm_reg`` x mean(log(|z|)^2) over their
        embeddings, plus ``ref_weight`` x mean(1 - cos) between their interface and the input
        reference."""
        return self.penalized(encoder, x)[1] if self.penalizes else x.new_zeros(())

    def _penalty(self, z: Tensor, relative: Tensor, inputs: Tensor, anchors: Tensor) -> Tensor:
        """The penalties from the embeddings ``z`` and relative vectors of ``inputs`` (the states,
        then the anchors)."""
        total = z.new_zeros(())
        if self.spec.norm_reg:
            total = total + self.spec.norm_reg * z.norm(dim=-1).clamp_min(1e-12).log().pow(2).mean()
        if self.spec.ref_weight:
            total = total + self.spec.ref_weight * self._reference_gap(relative, inputs, anchors)
        return total

    def reference_gap(self, encoder: Callable[[Tensor], Tensor], x: Tensor) -> Tensor:
        """mean(1 - cos) between the interface and the input reference (:func:`input_reference`,
        at the spec's ``ref_bandwidth``) over the states ``x`` and the anchors: the distance that
        ``ref_weight`` penalises, unweighted (also the pull of :mod:`ps_ray.nets.consolidate`)."""
        flat, anchors = self._flatten(x)
        inputs = torch.cat([flat, anchors], 0)
        return self._reference_gap(self(encoder, inputs), inputs, anchors)

    def _reference_gap(self, relative: Tensor, inputs: Tensor, anchors: Tensor) -> Tensor:
        target = self._post(input_reference(inputs, anchors, self.spec.ref_bandwidth))
        return (1 - F.cosine_similarity(relative, target, dim=-1)).mean()

    def extra_repr(self) -> str:
        return f"anchors={tuple(self.anchors.shape)}, {self.spec}"
