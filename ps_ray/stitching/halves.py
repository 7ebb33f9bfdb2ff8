"""A stitch with one half untrained: what takes a few-shot head start apart (docs/transfer.md).

A stitched start may fine-tune faster than scratch because of its task module, its robot module,
or only because some trained robot module of the target robot drives the arm. Each half is put
beside a fresh other half: ``robot_module`` keeps the pair's robot module under a fresh task
module, ``task_module`` keeps its task module over a fresh robot module. The fresh half has the
stitch's method, widths and anchors (the task source's, those of the target task), weights drawn
from the given seed and empty normaliser statistics, as a run from scratch starts.
"""

from __future__ import annotations

import torch

from ps_ray.nets.from_signature import build_nets
from ps_ray.nets.sac import SACNets
from ps_ray.specs.modes import TrialKind
from ps_ray.specs.trial import HALVES
from ps_ray.stitching.rule import check_stitchable
from ps_ray.stitching.stitch import PolicySource, load_source, stitch_policies
from ps_ray.store.signature import Signature


def half_stitch(
    task_from: PolicySource, robot_from: PolicySource, keep: str, seed: int
) -> tuple[SACNets, Signature]:
    """The pair's stitch with the half ``keep`` names from its source and the other half fresh."""
    if keep not in HALVES:
        raise ValueError(f"keep must be one of {HALVES}, got {keep!r}")
    nets_t, sig_t = load_source(task_from)
    nets_r, sig_r = load_source(robot_from)
    signature = check_stitchable(sig_t, sig_r)
    anchors = nets_t.actor.anchors
    with torch.random.fork_rng(devices=[]):  # the caller's torch RNG stays where it was
        torch.manual_seed(seed)
        fresh = build_nets(signature, None if anchors is None else anchors.detach().cpu())
    if fresh.actor.task.projection_off and not signature.projection_off:
        fresh.actor.task.switch_relative_on()  # a deferred projection: on, as in the sources it meets
    if keep == TrialKind.ROBOT_MODULE:
        return stitch_policies((fresh, signature), (nets_r, sig_r))
    return stitch_policies((nets_t, sig_t), (fresh, signature))
