"""Post-hoc latent translation (Maiorca et al., NeurIPS 2023; SAPS, Ricciardi et al. 2025).

At stitch time, a map from task module A's latent to the latent that robot module B expects is
fitted on matched pairs: the same task states through A's task module and through B's own task
module. No env steps, no gradient steps. Each side is centred and scaled by one number (the RMS
of its centred vectors) over the fit states; the map is fitted between the scaled spaces, then
de-scaled into B's space. Isotropic scaling, not per-dimension: per-dimension scaling distorts
angles, so a rotation between two spaces would no longer be a rotation between the scaled ones.
The result is one affine map ``z_B = z_A @ weight + bias`` held as buffers of a
:class:`LatentTranslation`, so it is saved with the stitched policy's tensors.

- ``orthogonal``: Procrustes, R = U V^T from the SVD of X^T Y (a rotation/reflection only);
- ``affine``: ridge regression [X, 1] W = Y (any linear map plus an unpenalised offset), its
  strength chosen by leave-one-out cross-validation on the fit pairs themselves (scikit-learn's
  ``RidgeCV``, exact LOO from one SVD; no env steps) and returned with the map;
- ``affine_lstsq``: plain least squares, the fit before the ridge, kept only to show why it was
  replaced. A 128-wide latent gives 129 unknowns per output, but trained latents have an
  effective rank of about 40-60; at about as many rows as unknowns plain least squares fits the
  noise in the weak directions and its predictions blow up (the interpolation peak:
  docs/results/confirm.md, "How many outcome scenes the fit needs"). The ridge keeps them small.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import torch
from torch import Tensor, nn

from ps_ray.errors import UserError
from ps_ray.specs.names import LATENT_TRANSLATIONS

SCALE_EPS = 1e-8
# the ridge strengths cross-validation chooses from, on the scaled latents (mean squared row norm 1),
# as scikit-learn's RidgeCV applies them: to the summed squared error of the N fit pairs
RIDGE_GRID = tuple(np.logspace(-8, 4, 49))


class AffineFit(NamedTuple):
    """``dst ≈ src @ weight + bias``; ``ridge``: the strength the fit chose (0: none)."""

    weight: np.ndarray
    bias: np.ndarray
    ridge: float = 0.0


def check_kind(kind: str) -> str:
    if kind not in LATENT_TRANSLATIONS:
        raise UserError(f"unknown translation {kind!r}; expected one of {list(LATENT_TRANSLATIONS)}")
    return kind


def fit_translation(src: np.ndarray, dst: np.ndarray, kind: str) -> AffineFit:
    """The map with ``dst ≈ src @ weight + bias`` for matched rows of src (N x Da), dst (N x Db)."""
    check_kind(kind)
    src, dst = np.asarray(src, np.float64), np.asarray(dst, np.float64)
    if src.ndim != 2 or dst.ndim != 2 or len(src) != len(dst) or len(src) < 2:
        raise ValueError(f"need matched (N, D) latents with N >= 2, got {src.shape} and {dst.shape}")
    mu_a, mu_b = src.mean(0), dst.mean(0)
    sd_a, sd_b = _rms(src - mu_a), _rms(dst - mu_b)
    x, y = (src - mu_a) / sd_a, (dst - mu_b) / sd_b
    if kind == "orthogonal":
        width = max(x.shape[1], y.shape[1])  # zero-pad the narrower side
        xp = np.pad(x, ((0, 0), (0, width - x.shape[1])))
        yp = np.pad(y, ((0, 0), (0, width - y.shape[1])))
        u, _, vt = np.linalg.svd(xp.T @ yp)
        linear = (u @ vt)[: x.shape[1], : y.shape[1]]
        offset, ridge = np.zeros(y.shape[1]), 0.0
    elif kind == "affine_lstsq":
        solution, *_ = np.linalg.lstsq(np.hstack([x, np.ones((len(x), 1))]), y, rcond=None)
        linear, offset, ridge = solution[:-1], solution[-1], 0.0
    else:
        linear, offset, ridge = _ridge(x, y)
    # de-scale: z_b = ((z_a - mu_a) / sd_a @ linear + offset) * sd_b + mu_b
    weight = linear * (sd_b / sd_a)
    bias = (offset - (mu_a / sd_a) @ linear) * sd_b + mu_b
    return AffineFit(weight, bias, ridge)


def _ridge(x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """(linear, offset, strength): one ridge strength for every output, the one of
    :data:`RIDGE_GRID` with the least leave-one-out squared error summed over outputs."""
    from sklearn.linear_model import RidgeCV

    model = RidgeCV(alphas=RIDGE_GRID, fit_intercept=True).fit(x, y)
    return model.coef_.T, model.intercept_, float(model.alpha_)


def _rms(centred: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.sum(centred**2, axis=1)))) + SCALE_EPS


class LatentTranslation(nn.Module):
    """``z @ weight + bias``; fitted, never trained (buffers, not parameters). ``ridge`` is the
    strength its fit chose (an attribute, not saved: a loaded map is applied, never refitted)."""

    weight: Tensor
    bias: Tensor

    def __init__(self, in_dim: int, out_dim: int) -> None:
        super().__init__()
        self.register_buffer("weight", torch.eye(in_dim, out_dim))
        self.register_buffer("bias", torch.zeros(out_dim))
        self.ridge = float("nan")

    @classmethod
    def fitted(cls, src: np.ndarray, dst: np.ndarray, kind: str) -> LatentTranslation:
        fit = fit_translation(src, dst, kind)
        module = cls(*fit.weight.shape)
        module.weight.copy_(torch.as_tensor(fit.weight))
        module.bias.copy_(torch.as_tensor(fit.bias))
        module.ridge = fit.ridge
        return module

    def forward(self, z: Tensor) -> Tensor:
        return z @ self.weight.to(z.dtype) + self.bias.to(z.dtype)

    def extra_repr(self) -> str:
        return f"{self.weight.shape[0]} -> {self.weight.shape[1]}"
