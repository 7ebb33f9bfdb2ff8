"""An aligned stitch as an ordinary policy: its fitted latent map folded into the robot module.

A stitch aligned at stitch time (:mod:`ps_ray.nets.translation`) hands its robot module
``z @ W + b`` in place of the task module's latent ``z``. The robot module's first layer is linear in
its latent columns L, so the map folds into that layer exactly: ``L (z W + b) = (L W^T) z + L b``.
What comes out has the architecture of an unaligned stitch, acts as the aligned one does, and can
start a training run (few-shot's ``aligned`` start), where every weight trains, the map's share
included. Methods that drop latent units in training (devin) do not fold: dropout before the map
is not dropout after it.
"""

from __future__ import annotations

import copy
import dataclasses

import torch

from ps_ray.errors import UserError
from ps_ray.nets.from_signature import signature_of
from ps_ray.nets.sac import NET_NAMES, SACNets
from ps_ray.specs.methods import method_spec
from ps_ray.specs.names import LATENT_TRANSLATIONS
from ps_ray.store.signature import Signature


def fold_translation(nets: SACNets, signature: Signature) -> tuple[SACNets, Signature]:
    """New nets equal to ``nets`` (a stitch with a fitted latent map) with no map: each net's map
    folded into the first layer of its robot module; the signature names no translation."""
    if signature.translation not in LATENT_TRANSLATIONS:
        raise UserError(
            f"only a stitch with a fitted latent map folds ({', '.join(LATENT_TRANSLATIONS)}), "
            f"got translation {signature.translation or 'none'!r}"
        )
    if method_spec(signature.method).dropout > 0:
        raise UserError(
            f"cannot fold a {signature.method} stitch's latent map: its latent dropout comes before it"
        )
    folded = copy.deepcopy(nets)
    with torch.no_grad():
        for name in NET_NAMES:
            net = getattr(folded, name)
            first, width = net.robot.head[0], net.latent_dim  # the latent's columns come first
            latent_columns = first.weight[:, :width].clone()
            first.weight[:, :width] = latent_columns @ net.translate.weight.T.to(first.weight.dtype)
            first.bias += latent_columns @ net.translate.bias.to(first.bias.dtype)
            net.translate = None
    unaligned = dataclasses.replace(signature, translation="")
    rebuilt = signature_of(folded, unaligned.method, unaligned.interface_dim, unaligned.hidden)
    if rebuilt != unaligned:  # a bug, never bad input
        raise ValueError(f"folded nets do not match their signature: {rebuilt.mismatches(unaligned)}")
    return folded, unaligned
