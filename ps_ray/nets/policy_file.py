"""Policy files: safetensors with the interface signature that stitching checks.

One file holds the actor, both critics and both target critics (normaliser statistics and PS
anchors included, as buffers). The signature travels in the safetensors metadata
(:mod:`ps_ray.store.signature`). Loading never unpickles and refuses any file whose metadata or
tensor names do not match what the signature builds (:mod:`ps_ray.nets.from_signature`), with one
line naming the file and the problem.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

from safetensors import SafetensorError, safe_open
from safetensors.torch import save_file
from torch import nn

from ps_ray.data.anchors import AnchorSet
from ps_ray.errors import UserError
from ps_ray.nets.from_signature import ANCHORS_KEY, nets_from_state, nets_state
from ps_ray.nets.sac import SACNets
from ps_ray.specs.methods import spec_json
from ps_ray.store.atomic import atomic_path
from ps_ray.store.signature import FORMAT, Signature, read_signature


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
