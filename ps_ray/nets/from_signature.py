"""The nets a policy signature describes, and the signature of given nets: untrained nets built
from a signature, a state loaded into them strictly (shapes checked first on the meta device),
and the five SAC nets' state as one flat dict of tensors (the policy file's tensors,
:mod:`ps_ray.nets.policy_file`)."""

from __future__ import annotations

import torch
from torch import nn

from ps_ray.data.anchors import anchor_hash
from ps_ray.errors import UserError
from ps_ray.nets.sac import NET_NAMES, SACNets, build_sac_nets
from ps_ray.specs.methods import method_spec, spec_json
from ps_ray.specs.names import LATENT_TRANSLATIONS
from ps_ray.store.signature import Signature

ANCHORS_KEY = "actor.task.relative.anchors"


def signature_of(
    nets: nn.Module, method: str, interface_dim: int, hidden: int, translation: str = ""
) -> Signature:
    dims = nets.actor.dims
    latent = translation in LATENT_TRANSLATIONS  # "anchors" moves the anchors, adds no map
    if latent != (getattr(nets.actor, "translate", None) is not None):
        raise ValueError(
            f"nets {'lack' if latent else 'carry'} a latent translation, "
            f"signature says {translation or 'none'!r}"
        )
    spec = nets.actor.spec
    if method_spec(method).name != spec.name:
        raise ValueError(f"nets built as {spec.name!r}, signature says {method!r}")
    return Signature(
        projection_off=nets.actor.task.projection_off,
        settings=spec_json(spec),
        method=spec.name,
        interface_dim=interface_dim,
        hidden=hidden,
        anchor_hash=""
        if nets.actor.anchors is None
        else anchor_hash(nets.actor.anchors.detach().cpu().numpy()),
        task_dim=dims.task_dim,
        robot_dim=dims.robot_dim,
        action_dim=dims.action_dim,
        translation=translation,
    )


def nets_state(nets: nn.Module) -> dict[str, torch.Tensor]:
    """State of the five SAC nets of any container that has them (SACNets or the RLlib module)."""
    return {
        f"{name}.{k}": v.detach().cpu().contiguous()
        for name in NET_NAMES
        for k, v in getattr(nets, name).state_dict().items()
    }


def nets_from_state(state: dict[str, torch.Tensor], signature: Signature, source: str = "state") -> SACNets:
    """Build the nets a signature describes and load `state` into them, strictly. The tensors'
    shapes are checked first against nets built on the meta device (no memory), so a signature
    that claims huge sizes costs nothing."""
    anchors = state.get(ANCHORS_KEY)
    if (anchor_hash(anchors.numpy()) if anchors is not None else "") != signature.anchor_hash:
        raise UserError(f"{source}: anchors do not match the signature's anchor hash")
    with torch.device("meta"):
        expected = _shapes(build_nets(signature, anchors, source))
    found = {k: tuple(v.shape) for k, v in state.items()}
    missing, unexpected = sorted(expected.keys() - found.keys()), sorted(found.keys() - expected.keys())
    wrong_shape = [k for k in expected.keys() & found.keys() if expected[k] != found[k]]
    if missing or unexpected or wrong_shape:
        raise UserError(
            f"{source}: tensors do not match the signature (missing {missing[:3]}, "
            f"unexpected {unexpected[:3]}, wrong shape {wrong_shape[:3]})"
        )
    # The initial weights drawn here are all overwritten: draw them outside the caller's random
    # stream, so writing or reading a policy file mid-run does not change the run.
    with torch.random.fork_rng(devices=[]):
        nets = build_nets(signature, anchors, source)
    load_nets_state(nets, state)
    return nets


def build_nets(signature: Signature, anchors: torch.Tensor | None, source: str = "nets") -> SACNets:
    """Untrained nets of a signature (its resolved method, widths, dims; the given anchors)."""
    try:
        nets = build_sac_nets(
            signature.spec,
            signature.dims,
            interface_dim=signature.interface_dim,
            hidden=signature.hidden,
            anchors=None if anchors is None else anchors.numpy(),
        )
    except ValueError as e:
        raise UserError(f"{source}: {e}") from None
    if signature.translation in LATENT_TRANSLATIONS:  # "anchors" moves anchors, adds no map
        attach_translations(nets)
    return nets


def _shapes(nets: nn.Module) -> dict[str, tuple[int, ...]]:
    nets_shapes = {name: getattr(nets, name).state_dict() for name in NET_NAMES}
    return {f"{name}.{k}": tuple(v.shape) for name, state in nets_shapes.items() for k, v in state.items()}


def attach_translations(nets: nn.Module) -> None:
    """Give every net an (identity) latent translation of its latent width, to be loaded or fitted."""
    from ps_ray.nets.translation import LatentTranslation

    for name in NET_NAMES:
        net = getattr(nets, name)
        net.translate = LatentTranslation(net.latent_dim, net.latent_dim)


def load_nets_state(nets: nn.Module, state: dict[str, torch.Tensor]) -> None:
    """Inverse of nets_state: load every net of a container (SACNets or the RLlib module), strictly."""
    for name in NET_NAMES:
        prefix = name + "."
        getattr(nets, name).load_state_dict(
            {k[len(prefix) :]: v for k, v in state.items() if k.startswith(prefix)}, strict=True
        )
