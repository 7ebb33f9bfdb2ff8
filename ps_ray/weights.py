"""Policy weights as safetensors, with the interface signature that stitching checks.

One file holds the actor, both critics and both target critics (normaliser statistics and PS
anchors included, as buffers). The signature travels in the safetensors metadata. Loading never
unpickles and refuses any file whose metadata or tensor names do not match what the signature
builds, with one line naming the file and the problem.
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass
from pathlib import Path

import torch
from safetensors import SafetensorError, safe_open
from safetensors.torch import save_file
from torch import nn

from ps_ray.data.anchors import AnchorSet, anchor_hash
from ps_ray.defaults import MAX_WIDTH
from ps_ray.errors import UserError
from ps_ray.nets.modular import NetDims
from ps_ray.nets.sac import NET_NAMES, SACNets, build_sac_nets
from ps_ray.specs.methods import MethodSpec, method_spec, spec_from_dict, spec_json
from ps_ray.store.atomic import atomic_path

FORMAT = "ps_ray.policy/1"
ANCHORS_KEY = "actor.task.relative.anchors"


@dataclass(frozen=True)
class Signature:
    """What must agree for two modules to be stitched."""

    method: str  # the method's key (ps_ray.specs.methods)
    interface_dim: int
    hidden: int
    anchor_hash: str  # "" for methods without anchors
    task_dim: int
    robot_dim: int
    action_dim: int
    translation: str = ""  # a stitched policy's fitted latent translation ("" none, or its kind)
    # a deferred relative projection (MethodSpec.defer_relative) still off: the cut is the raw
    # latent until the run finishes, so no other source's robot module reads it
    projection_off: bool = False
    # the resolved method, every setting (JSON): the nets are built from it, not from the menu,
    # so a file keeps its meaning whatever the presets become. "" in files written before it
    # existed (they name a preset or an old row, resolved when read: :func:`read_signature`)
    settings: str = ""

    @property
    def dims(self) -> NetDims:
        return NetDims(self.task_dim, self.robot_dim, self.action_dim)

    @property
    def spec(self) -> MethodSpec:
        return spec_from_dict(json.loads(self.settings)) if self.settings else method_spec(self.method)

    def mismatches(self, other: Signature, fields: tuple[str, ...] | None = None) -> list[str]:
        names = fields or tuple(f.name for f in dataclasses.fields(self))
        return [
            f"{n}: {getattr(self, n)!r} vs {getattr(other, n)!r}"
            for n in names
            if getattr(self, n) != getattr(other, n)
        ]


def signature_of(
    nets: nn.Module, method: str, interface_dim: int, hidden: int, translation: str = ""
) -> Signature:
    dims = nets.actor.dims
    if bool(translation) != (getattr(nets.actor, "translate", None) is not None):
        raise ValueError(
            f"nets {'lack' if translation else 'carry'} a latent translation, "
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


def save_policy(
    path: str | Path, nets: nn.Module, signature: Signature, extra: dict[str, str] | None = None
) -> Path:
    """Write atomically: a crash leaves either the old file or the new one, never half of one."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    if not signature.settings:  # every file written names its resolved method
        signature = dataclasses.replace(signature, settings=spec_json(signature.spec))
    metadata = {"format": FORMAT, "signature": json.dumps(dataclasses.asdict(signature)), **(extra or {})}
    with atomic_path(path) as tmp:
        save_file(nets_state(nets), str(tmp), metadata=metadata)
    return path


def read_signature(path: str | Path) -> tuple[Signature, dict[str, str]]:
    """The signature and metadata of a policy file, without loading its tensors."""
    path = Path(path)
    try:
        with safe_open(str(path), framework="pt") as f:
            metadata = f.metadata() or {}
    except (SafetensorError, OSError, ValueError) as e:
        raise UserError(f"{path}: not a ps_ray policy file ({e})") from None
    if metadata.get("format") != FORMAT:
        raise UserError(
            f"{path}: not a ps_ray policy file (format {metadata.get('format')!r}, expected {FORMAT!r})"
        )
    try:
        signature = Signature(**json.loads(metadata["signature"]))
    except (KeyError, TypeError, json.JSONDecodeError) as e:
        raise UserError(f"{path}: corrupt policy signature ({e})") from None
    problem = signature_problem(signature)
    if problem:
        raise UserError(f"{path}: bad policy signature: {problem}")
    if not signature.settings:  # written before the resolved method was stored: resolve its name
        spec = method_spec(signature.method)
        signature = dataclasses.replace(signature, method=spec.name, settings=spec_json(spec))
    return signature, metadata


def signature_problem(signature: Signature) -> str | None:
    """What makes a signature unusable (wrong types, absurd sizes, unknown names), or None."""
    from ps_ray.names import TRANSLATIONS

    if not isinstance(signature.method, str) or not isinstance(signature.settings, str):
        return f"method and settings must be strings, got {signature.method!r} and {signature.settings!r}"
    try:
        spec = signature.spec
    except (UserError, ValueError, json.JSONDecodeError) as e:
        return str(e)
    if signature.settings and spec.name != signature.method:
        return f"method {signature.method!r} disagrees with its settings (named {spec.name!r})"
    for name in ("interface_dim", "hidden", "task_dim", "robot_dim", "action_dim"):
        value = getattr(signature, name)
        if isinstance(value, bool) or not isinstance(value, int) or not 0 < value <= MAX_WIDTH:
            return f"{name} must be an integer in 1..{MAX_WIDTH}, got {value!r}"
    if not isinstance(signature.anchor_hash, str):
        return f"anchor_hash must be a string, got {signature.anchor_hash!r}"
    if signature.translation not in ("", *TRANSLATIONS):
        return f"unknown translation {signature.translation!r}; valid: none, {', '.join(TRANSLATIONS)}"
    if not isinstance(signature.projection_off, bool):
        return f"projection_off must be true or false, got {signature.projection_off!r}"
    return None


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
    if signature.translation:
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


def policy_anchor_set(path: str | Path) -> AnchorSet:
    """The anchor set stored in a PS policy file (e.g. a stitched start for few-shot)."""
    signature, _ = read_signature(path)
    with safe_open(str(path), framework="pt") as f:
        if ANCHORS_KEY not in f.keys():
            raise UserError(f"{path}: a {signature.method!r} policy has no anchors")
        return AnchorSet.of(f.get_tensor(ANCHORS_KEY).numpy(), {"source": str(path)})


def load_policy(path: str | Path) -> tuple[SACNets, Signature]:
    """Rebuild the nets a policy file describes and load every tensor, targets included."""
    path = Path(path)
    signature, _ = read_signature(path)
    try:
        with safe_open(str(path), framework="pt") as f:
            state = {k: f.get_tensor(k) for k in f.keys()}
    except (SafetensorError, OSError, ValueError) as e:
        raise UserError(f"{path}: unreadable tensors ({e})") from None
    nets = nets_from_state(state, signature, str(path))
    if nets.actor.task.projection_off != signature.projection_off:
        raise UserError(f"{path}: the relative projection's switch disagrees with the signature")
    return nets, signature
