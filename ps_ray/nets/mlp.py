"""The one MLP builder every method uses."""

from __future__ import annotations

from collections.abc import Sequence

from torch import nn


def mlp(
    in_dim: int,
    hidden: Sequence[int],
    out_dim: int,
    *,
    dropout: float = 0.0,
    out_act: bool = False,
) -> nn.Sequential:
    """Linear + ReLU (+ Dropout if ``dropout > 0``) per hidden width, then a final Linear.

    ``out_act=True`` appends a ReLU after the final Linear (used by the plain baseline's bottom half,
    whose output is a hidden layer of the full MLP). PyTorch default initialisation.
    """
    layers: list[nn.Module] = []
    width = in_dim
    for h in hidden:
        layers += [nn.Linear(width, h), nn.ReLU()]
        if dropout > 0:
            layers.append(nn.Dropout(dropout))
        width = h
    layers.append(nn.Linear(width, out_dim))
    if out_act:
        layers.append(nn.ReLU())
    return nn.Sequential(*layers)
