"""A policy file's signature: what must agree for two modules to be stitched, stored in the
safetensors metadata of the file (``ps_ray.nets.policy_file`` writes and loads the tensors). Read here
without torch: the metadata alone, never a tensor, never a pickle.

The one place that knows the format's versions: every reader gets a current :class:`Signature`
from :func:`read_signature`, whatever version the file is (:func:`upgrade`).
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass
from pathlib import Path

from safetensors import SafetensorError, safe_open

from ps_ray.errors import UserError
from ps_ray.specs.defaults import MAX_WIDTH
from ps_ray.specs.dims import NetDims
from ps_ray.specs.methods import MethodSpec, method_spec, spec_from_dict, spec_json
from ps_ray.specs.old_methods import upgrade_name
from ps_ray.store.formats import POLICY

# 1: ``settings`` may be "" (the method is then a preset or an older menu name, resolved when read)
# 2: ``settings`` always holds the resolved method
FORMAT = POLICY.id
FORMATS = POLICY.readable  # the versions this code reads


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
    def stitchable(self) -> bool:
        """Whether its modules may meet another source's: its interface is its method's final one
        (the one question stitching, the controls and the report ask of a policy file)."""
        return not self.projection_off

    @property
    def dims(self) -> NetDims:
        """The widths the nets are built from."""
        return NetDims(self.task_dim, self.robot_dim, self.action_dim)

    @property
    def spec(self) -> MethodSpec:
        """The resolved method: its settings, or (a version-1 file's, without them) the preset or
        old row it names."""
        if self.settings:
            return spec_from_dict(json.loads(self.settings))
        return method_spec(upgrade_name(self.method))

    def mismatches(self, other: Signature, fields: tuple[str, ...] | None = None) -> list[str]:
        names = fields or tuple(f.name for f in dataclasses.fields(self))
        return [
            f"{n}: {getattr(self, n)!r} vs {getattr(other, n)!r}"
            for n in names
            if getattr(self, n) != getattr(other, n)
        ]


def read_signature(path: str | Path) -> tuple[Signature, dict[str, str]]:
    """The signature and metadata of a policy file, without loading its tensors."""
    path = Path(path)
    try:
        with safe_open(str(path), framework="numpy") as f:
            metadata = f.metadata() or {}
    except (SafetensorError, OSError, ValueError) as e:
        raise UserError(f"{path}: not a ps_ray policy file ({e})") from None
    fmt = metadata.get("format")
    if fmt not in FORMATS:
        raise UserError(
            f"{path}: not a ps_ray policy file (format {fmt!r}; this code reads {', '.join(FORMATS)})"
        )
    try:
        signature = Signature(**json.loads(metadata["signature"]))
    except (KeyError, TypeError, json.JSONDecodeError) as e:
        raise UserError(f"{path}: corrupt policy signature ({e})") from None
    problem = signature_problem(signature)
    if problem is None and fmt != FORMATS[0] and not signature.settings:
        problem = f"a {fmt} file must hold its method's settings"
    if problem:
        raise UserError(f"{path}: bad policy signature: {problem}")
    return upgrade(signature), metadata


def upgrade(signature: Signature) -> Signature:
    """A signature read from any version as the current version writes it: a version-1 file
    without settings names a preset or an older menu name, resolved here; a setting added after
    a file was written takes its default, as the nets it was trained with were built."""
    spec = signature.spec  # a version-1 file's names a preset or an old row: :attr:`Signature.spec`
    return dataclasses.replace(signature, method=spec.name, settings=spec_json(spec))


def signature_problem(signature: Signature) -> str | None:
    """What makes a signature unusable (wrong types, absurd sizes, unknown names), or None."""
    from ps_ray.specs.names import TRANSLATIONS

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
