"""Policy stitching: the task modules of one policy with the robot modules of another.

docs/authors_code.md §6: the task module comes from the policy trained on the *target task* with another
robot, the robot module from the policy trained with the *target robot* on another task. All five
nets are stitched (actor, both critics and both target critics), so a stitched policy can start
few-shot training; zero-shot evaluation uses the actor alone (:mod:`ps_ray.stitching.evaluate`).

Which pairs meet and what must agree for them live in :mod:`ps_ray.stitching.rule` (torch-free,
so the cost model asks the same rule), and a sweep's combinations in :mod:`ps_ray.stitching.matrix`;
here the nets are built and translated.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import torch
from torch import nn

from ps_ray.data.anchors import anchor_hash
from ps_ray.envs.core import env_widths
from ps_ray.errors import UserError
from ps_ray.nets.from_signature import signature_of
from ps_ray.nets.policy_file import load_policy
from ps_ray.nets.sac import NET_NAMES, SACNets, build_sac_nets
from ps_ray.nets.translation import LatentTranslation, check_kind
from ps_ray.specs.dims import NetDims
from ps_ray.specs.names import TRANSLATIONS, EnvPart
from ps_ray.stitching.rule import (
    EnvSpec,
    check_stitchable,
)
from ps_ray.stitching.zoo import ZooEntry
from ps_ray.store.signature import Signature

PolicySource = str | Path | ZooEntry | tuple[SACNets, Signature]


# -- target envs ----------------------------------------------------------------------------------
def env_dims(robot: EnvPart, task: EnvPart) -> NetDims:
    """The network dims of ``make(robot, task)``, without building it."""
    return NetDims(*env_widths(robot, task))


# -- stitching ------------------------------------------------------------------------------------
def load_source(source: PolicySource) -> tuple[SACNets, Signature]:
    if isinstance(source, tuple):
        return source
    path = Path(source.path if isinstance(source, ZooEntry) else source)
    if not path.is_file():
        raise UserError(f"{path}: no such policy file")
    return load_policy(path)


def stitch_policies(
    task_from: PolicySource,
    robot_from: PolicySource,
    *,
    target: EnvSpec | None = None,
    translation: str | None = None,
    fit_states: np.ndarray | tuple[np.ndarray, np.ndarray] | None = None,
) -> tuple[SACNets, Signature]:
    """New nets: every net's task module from ``task_from``, its robot module from ``robot_from``.

    The results own copies of the tensors (normaliser statistics and anchors included); target critics
    are stitched from the sources' target critics. Stitching a policy with itself gives back exactly
    that policy. ``translation`` ("orthogonal", "affine" or "affine_lstsq") fits a latent map per
    net on ``fit_states`` between the two policies' task modules (:mod:`ps_ray.nets.translation`):
    task inputs (N x task_dim) through both, or matched pairs (states of ``task_from``'s task,
    states of ``robot_from``'s own task: :mod:`ps_ray.stitching.outcomes`). ``"anchors"`` re-anchors
    instead: ``fit_states`` (K x task_dim) replace the task modules' anchors, row j the task-X state
    matched to the robot module's anchor j (:func:`ps_ray.stitching.outcomes. matched_anchors`). The
    signature names either.
    """
    nets_t, sig_t = load_source(task_from)
    nets_r, sig_r = load_source(robot_from)
    if sig_t.translation or sig_r.translation:
        raise UserError("cannot stitch a policy that is itself a translated stitch; use its sources")
    signature = check_stitchable(sig_t, sig_r, target)
    if translation not in (None, *TRANSLATIONS):
        raise UserError(f"unknown translation {translation!r}; valid: none, {', '.join(TRANSLATIONS)}")
    anchors = nets_t.actor.anchors
    anchors = None if anchors is None else anchors.detach().cpu().numpy()
    if translation == "anchors":
        anchors = _matched_anchors(anchors, fit_states, sig_t.method)
        signature = dataclasses.replace(signature, translation=translation, anchor_hash=anchor_hash(anchors))
    elif translation is not None:
        check_kind(translation)
        if fit_states is None:
            raise UserError("a translated stitch needs fit_states (task inputs for the fit)")
        if sig_t.task_dim != sig_r.task_dim and not isinstance(fit_states, tuple):
            raise UserError(
                f"cannot translate: the robot module's own task module takes "
                f"{sig_r.task_dim}-D task inputs, the target task has {sig_t.task_dim}"
            )
        signature = dataclasses.replace(signature, translation=translation)
    nets = build_sac_nets(
        signature.method,
        signature.dims,
        interface_dim=signature.interface_dim,
        hidden=signature.hidden,
        anchors=anchors,
    )
    for name in NET_NAMES:
        net = getattr(nets, name)
        net.task.load_state_dict(getattr(nets_t, name).task.state_dict(), strict=True)
        net.robot.load_state_dict(getattr(nets_r, name).robot.state_dict(), strict=True)
        if translation == "anchors" and net.task.relative is not None:
            net.task.relative.anchors.copy_(torch.as_tensor(anchors))
        elif translation is not None and translation != "anchors":
            net.translate = fit_net_translation(
                getattr(nets_t, name), getattr(nets_r, name), fit_states, translation
            )
    rebuilt = signature_of(
        nets, signature.method, signature.interface_dim, signature.hidden, translation=signature.translation
    )
    if rebuilt != signature:  # the anchors the nets carry are the ones the signature names
        raise ValueError(f"stitched nets do not match their signature: {rebuilt.mismatches(signature)}")
    return nets, signature


def _matched_anchors(anchors: np.ndarray | None, matched, method: str) -> np.ndarray:
    """The re-anchored stitch's anchors, checked against the ones they replace."""
    if anchors is None:
        raise UserError(f"cannot re-anchor a {method} stitch: it has no relative projection")
    if matched is None or isinstance(matched, tuple):
        raise UserError("a re-anchored stitch needs its matched anchors (K x task_dim) as fit_states")
    matched = np.asarray(matched, np.float32)
    if matched.shape != anchors.shape:
        raise UserError(
            f"matched anchors of shape {matched.shape} cannot replace anchors of shape {anchors.shape}"
        )
    return matched


@torch.no_grad()
def fit_net_translation(
    net_t: nn.Module,
    net_r: nn.Module,
    states: np.ndarray | tuple[np.ndarray, np.ndarray],
    kind: str,
    seed: int = 0,
) -> LatentTranslation:
    """The map from ``net_t``'s task-module latent to ``net_r``'s on the same inputs, or on
    matched pairs of inputs (``states`` = (``net_t``'s, ``net_r``'s), row for row).

    Modular task modules see task inputs only. Plain's bottom half also sees the robot state (and,
    in a critic, the action): those are drawn from the robot source's own normaliser statistics
    (its Gaussian approximation of the robot states it was trained on) and uniform actions, the
    same draw for both sides."""
    paired = states if isinstance(states, tuple) else (states, states)
    task_in, task_in_r = (torch.as_tensor(np.asarray(s, np.float32)) for s in paired)
    if len(task_in) != len(task_in_r):
        raise ValueError(
            f"matched pairs need as many rows on each side, got {len(task_in)} and {len(task_in_r)}"
        )
    robot_in = action = None
    if not net_r.spec.modular:
        g = torch.Generator().manual_seed(seed)
        norm, task_dim = net_r.task.norm, net_t.dims.task_dim
        mean, std = norm.mean[task_dim:], norm.var[task_dim:].sqrt()
        robot_in = mean + std * torch.randn(len(task_in), len(mean), generator=g)
        if net_r.task.sees_action:
            action = torch.rand(len(task_in), net_r.dims.action_dim, generator=g) * 2 - 1
    src = net_t.task(task_in, robot_in, action).double().numpy()
    dst = net_r.task(task_in_r, robot_in, action).double().numpy()
    return LatentTranslation.fitted(src, dst, kind)


def translation_ridge(nets: SACNets) -> float | None:
    """The ridge strength the actor's latent translation chose (0 for a fit without one), or None
    for a stitch without a latent map (:mod:`ps_ray.nets.translation`)."""
    translate = getattr(nets.actor, "translate", None)
    return None if translate is None else float(translate.ridge)


def stitch_metadata(task_from: str, robot_from: str) -> dict[str, str]:
    """Provenance stored in a saved stitched policy's metadata."""
    return {"stitched_task_from": task_from, "stitched_robot_from": robot_from}
