"""Methods: a short menu of presets, and options that make any variant of one (no torch here).

A method is written as a preset name, or a preset followed by ``+option=value`` overrides:
``ps``, ``ps+norm=layer``, ``ps+relative_critics=false+consolidate_updates=2000``. A sweep YAML
may also write a mapping, ``{preset: ps, norm: layer}``. Either form resolves to one
:class:`MethodSpec`, whose :attr:`MethodSpec.name` is the canonical key: the preset plus the
options that differ from it, sorted. The key names the variant by its settings in trial names,
tables and MLflow; a policy file stores the resolved settings (:func:`spec_to_dict`), so a file
keeps loading whatever the menu becomes. docs/methods.md lists the presets and what was measured
for each option.

Options (see :class:`RelativeSpec` and :class:`ConsolidateSpec` for what each does):

- ``relative`` (true/false): a relative projection at the cut, with ``center``, ``norm``,
  ``scale``, ``anchor_grad``, ``norm_reg``, ``ref_weight``, ``ref_bandwidth``;
- ``relative_critics``: the critics' cut is relative too (false: the raw latent);
- ``defer_relative``: train on the raw latent, switch the projection on at consolidation;
- ``consolidate`` (true/false), ``consolidate_updates``, ``consolidate_pull``,
  ``consolidate_lr``, ``consolidate_batch_size``, ``consolidate_log_std_weight``;
- ``modular`` (false: plain, one MLP cut in the middle), ``interface_dim`` (a fixed width at the
  cut, 0: the sweep's interface_dim), ``dropout`` (on the latent at the robot module's input).
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from ps_ray.errors import UserError, describe
from ps_ray.specs.old_methods import LEGACY

REL_NORMS = ("none", "layer")
CENTERINGS = ("none", "mean", "standard")


@dataclass(frozen=True)
class RelativeSpec:
    """How the interface is computed from the embeddings of a batch and of the anchors.

    - ``center``: before the cosine, subtract the anchor embeddings' mean from both embeddings
      (``"mean"``), or also divide by their per-dimension std (``"standard"``, R3L, Ricciardi et
      al. 2025). Removes the common direction every ReLU embedding shares, so the cosines spread
      over [-1, 1] instead of clustering near 1. ``"mean"`` keeps the relative vector invariant to
      rotations, scalings *and* translations of the embedding space; ``"standard"`` gives up the
      rotation invariance (per-dimension scaling changes angles).
    - ``norm``: ``"layer"`` applies a parameter-free LayerNorm over the K similarities of each
      state (relreps' default output norm), a fixed function of the similarity vector.
    - ``scale``: a fixed multiplier on the result (an inverse temperature).
    - ``anchor_grad``: gradients flow through the anchor embeddings (the authors' way) or the
      anchors are embedded under ``torch.no_grad()`` (relreps' way). Values are equal either way.
    - ``norm_reg``: weight of a penalty mean(log(|z|)^2) over the embeddings of a batch and the
      anchors. The cosine makes the interface blind to |z|, so every optimiser step lengthens z
      and the direction's effective learning rate falls as 1/|z| (measured: |z| grows 54x in 16k
      env steps of PS on reach); the penalty's gradient is radial, so it holds |z| near 1.
    - ``ref_weight``: weight of a penalty mean(1 - cos) between the interface and a fixed
      reference interface of the *input* (Gaussian-kernel similarities of the anchor-standardised
      task input to the anchors, :func:`ps_ray.nets.relative.input_reference`): every source that
      shares the anchor set is pulled to the same function of the anchors.
    - ``ref_bandwidth``: the reference kernel's squared width as a multiple of the anchors' median
      squared distance (below 1: a finer reference, looser alignment).
    """

    center: str = "none"
    norm: str = "none"
    scale: float = 1.0
    anchor_grad: bool = True
    norm_reg: float = 0.0
    ref_weight: float = 0.0
    ref_bandwidth: float = 1.0

    def __post_init__(self) -> None:
        if self.center not in CENTERINGS:
            raise ValueError(f"unknown centring {self.center!r}; expected one of {list(CENTERINGS)}")
        if self.norm not in REL_NORMS:
            raise ValueError(f"unknown relative norm {self.norm!r}; expected one of {list(REL_NORMS)}")
        if not self.scale > 0:
            raise ValueError(f"relative scale must be positive, got {self.scale!r}")
        for name in ("norm_reg", "ref_weight"):
            if not getattr(self, name) >= 0:
                raise ValueError(f"{name} must be >= 0, got {getattr(self, name)!r}")
        if not self.ref_bandwidth > 0:
            raise ValueError(f"ref_bandwidth must be positive, got {self.ref_bandwidth!r}")


@dataclass(frozen=True)
class ConsolidateSpec:
    """Consolidation after training (:mod:`ps_ray.nets.consolidate`): ``updates`` Adam steps
    (``lr``) on minibatches of ``batch_size`` replay states, the interface's gap to the input
    reference weighted by ``pull``, the log-std error by ``log_std_weight``."""

    updates: int = 2000
    pull: float = 1.0
    lr: float = 3e-4
    batch_size: int = 256
    log_std_weight: float = 0.1

    def __post_init__(self) -> None:
        for name in ("updates", "batch_size"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f"consolidation {name} must be a positive integer, got {value!r}")
        if not self.lr > 0:
            raise ValueError(f"consolidation lr must be positive, got {self.lr!r}")
        for name in ("pull", "log_std_weight"):  # pull 0: distillation into the relative cut alone
            if not getattr(self, name) >= 0:
                raise ValueError(f"consolidation {name} must be >= 0, got {getattr(self, name)!r}")

    @property
    def rows(self) -> int:
        """States one consolidation reads: ``updates`` minibatches of ``batch_size``."""
        return self.updates * self.batch_size


@dataclass(frozen=True)
class MethodSpec:
    """Every setting of a method; ``name`` is its key (a preset, or a preset + options)."""

    name: str
    relative: RelativeSpec | None  # projection onto anchors (PS and its variants), None: raw latent
    modular: bool  # False for plain: the bottom half sees the whole state
    interface_dim: int | None  # fixed bottleneck width, or None = the caller's interface_dim
    dropout: float  # dropout on the latent, applied at the robot module's input
    relative_critics: bool = True  # False: only the actor's cut is relative
    consolidate: ConsolidateSpec | None = None  # align the actor's interface after training
    # True: the actor trains on the raw latent (the ablation's network, step for step) and its
    # relative projection is switched on by consolidation, which distils the actor into it
    defer_relative: bool = False
    # the task-input normaliser's statistics cover the goals training reads, hindsight ones
    # included (docs/transfer.md, "The normaliser sees hindsight goals"); false: the collected
    # steps only, as before that fix (`<preset>+hindsight_norm=false`, for before/after studies)
    hindsight_norm: bool = True

    def __post_init__(self) -> None:
        if self.relative is not None and not self.modular:
            raise ValueError("a relative interface needs a modular network (modular=true)")
        if self.consolidate is not None and self.relative is None:
            raise ValueError("consolidation needs a relative interface (relative=true)")
        if self.defer_relative and (self.consolidate is None or self.relative_critics):
            raise ValueError(
                "a deferred relative interface needs consolidation (which switches it on) and "
                "raw-latent critics (relative_critics=false)"
            )
        if not 0 <= self.dropout < 1:
            raise ValueError(f"dropout must be in [0, 1), got {self.dropout!r}")
        if self.interface_dim is not None and self.interface_dim < 1:
            raise ValueError(f"interface_dim must be positive, got {self.interface_dim!r}")

    def relative_for(self, critic: bool) -> RelativeSpec | None:
        """The projection at an actor's or a critic's cut (None: the raw latent)."""
        return None if critic and not self.relative_critics else self.relative

    def latent_dim(self, interface_dim: int, hidden: int) -> int:
        """Width at the cut: fixed (devin), the caller's interface_dim, or ``hidden`` for plain."""
        if not self.modular:
            return hidden
        return self.interface_dim if self.interface_dim is not None else interface_dim

    @property
    def uses_anchors(self) -> bool:
        """Whether the interface is relative to an anchor set (PS and its variants)."""
        return self.relative is not None


def _modular(name: str, interface_dim: int | None = None, dropout: float = 0.0) -> MethodSpec:
    return MethodSpec(name, None, modular=True, interface_dim=interface_dim, dropout=dropout)


# The menu. ps is the paper's method, unchanged; ps_distilled is the variant the studies ship
# (trains as the ablation, then its actor is distilled into the relative interface x 0.25 with
# LayerNorm and the pull to the input reference; docs/alignment.md). The rest are baselines.
PRESETS: dict[str, MethodSpec] = {
    spec.name: spec
    for spec in (
        MethodSpec("ps", RelativeSpec(), modular=True, interface_dim=None, dropout=0.0),
        MethodSpec(
            "ps_distilled",
            RelativeSpec(norm="layer", scale=0.25),
            modular=True,
            interface_dim=None,
            dropout=0.0,
            relative_critics=False,
            consolidate=ConsolidateSpec(updates=4000),  # a new interface to learn: twice the updates
            defer_relative=True,
        ),
        _modular("ablation"),
        _modular("devin", interface_dim=16, dropout=0.25),
        _modular("devin_large", dropout=0.25),
        MethodSpec("plain", None, modular=False, interface_dim=None, dropout=0.0),
    )
}


_RELATIVE = {f.name: f for f in dataclasses.fields(RelativeSpec)}
_CONSOLIDATE = {f"consolidate_{f.name}": f for f in dataclasses.fields(ConsolidateSpec)}
_TOP = {
    f.name: f for f in dataclasses.fields(MethodSpec) if f.name not in ("name", "relative", "consolidate")
}
_TYPES = {"relative": bool, "consolidate": bool, "interface_dim": int}
OPTIONS = ("relative", *_RELATIVE, "consolidate", *_CONSOLIDATE, *_TOP)


def _type(option: str) -> type:
    if option in _TYPES:
        return _TYPES[option]
    field = {**_RELATIVE, **_CONSOLIDATE, **_TOP}[option]
    return {"bool": bool, "int": int, "float": float, "str": str}[str(field.type)]


def _parse(option: str, value: Any) -> Any:
    """``value`` (text from a key, or a YAML scalar) as ``option``'s type."""
    kind = _type(option)
    if kind is bool:
        if isinstance(value, bool) or value in ("true", "false"):
            return value if isinstance(value, bool) else value == "true"
    elif kind is str:
        if isinstance(value, str):
            return value
    elif not isinstance(value, bool):
        try:
            number = float(value)
        except (TypeError, ValueError):
            number = None
        if number is not None and (kind is float or number.is_integer()):
            return int(number) if kind is int else number
    raise UserError(f"method option {option}: expected {describe(kind)}, got {value!r}")


def _options(spec: MethodSpec) -> dict[str, Any]:
    """Every option's value in ``spec``."""
    rel, con = spec.relative or RelativeSpec(), spec.consolidate or ConsolidateSpec()
    values = {"relative": spec.relative is not None, "consolidate": spec.consolidate is not None}
    values |= {k: getattr(rel, k) for k in _RELATIVE}
    values |= {k: getattr(con, k[len("consolidate_") :]) for k in _CONSOLIDATE}
    values |= {k: getattr(spec, k) for k in _TOP}
    values["interface_dim"] = spec.interface_dim or 0
    return values


def _with_options(base: MethodSpec, name: str, options: Mapping[str, Any]) -> MethodSpec:
    values = _options(base) | dict(options)
    switched = {}
    for switch, fields in (("relative", _RELATIVE), ("consolidate", _CONSOLIDATE)):
        given = [k for k in fields if k in options]
        if options.get(switch) is False and given:
            raise ValueError(f"{switch}=false contradicts {given[0]}")
        switched[switch] = values[switch] or bool(given)  # a setting of it switches it on
    relative, consolidate = switched["relative"], switched["consolidate"]
    return MethodSpec(
        name=name,
        relative=RelativeSpec(**{k: values[k] for k in _RELATIVE}) if relative else None,
        consolidate=ConsolidateSpec(**{k[len("consolidate_") :]: values[k] for k in _CONSOLIDATE})
        if consolidate
        else None,
        **{k: values[k] for k in _TOP} | {"interface_dim": values["interface_dim"] or None},
    )


def _text(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return format(value, "g")
    return str(value)


def key_of(preset: str, options: Mapping[str, Any]) -> str:
    """The canonical key: the preset and the options that differ from it, sorted by name (the
    settings of a projection or consolidation that is off are not shown)."""
    base, values = _options(PRESETS[preset]), _options(_with_options(PRESETS[preset], preset, options))
    hidden = {*([] if values["relative"] else _RELATIVE), *([] if values["consolidate"] else _CONSOLIDATE)}
    changed = sorted(k for k in OPTIONS if values[k] != base[k] and k not in hidden)
    return "+".join([preset, *(f"{k}={_text(values[k])}" for k in changed)])


def _split(method: str | Mapping) -> tuple[str, dict[str, Any]]:
    """(preset, options) of a key or a ``{preset: ..., option: value}`` mapping."""
    if isinstance(method, Mapping):
        raw = dict(method)
        preset = raw.pop("preset", None)
        if preset is None:
            raise UserError(f"method {_written(method)!r}: a mapping needs a preset ({', '.join(PRESETS)})")
    elif isinstance(method, str):
        if method in LEGACY:
            raise UserError(f"method {method!r} is an old name; write it as {LEGACY[method]!r}")
        preset, *pairs = method.split("+")
        raw = {}
        for pair in pairs:
            option, sep, value = pair.partition("=")
            if not sep:
                raise UserError(f"method {method!r}: option {pair!r} is not option=value")
            raw[option] = value
    else:
        raise UserError(f"method must be a name or a mapping with a preset, got {method!r}")
    if preset not in PRESETS:
        raise UserError(f"unknown method {preset!r}; valid presets: {', '.join(PRESETS)} (+option=value)")
    for option in raw:
        if option not in OPTIONS:
            raise UserError(
                f"method {_written(method)!r}: unknown option {option!r}; valid: {', '.join(OPTIONS)}"
            )
    return preset, {k: _parse(k, v) for k, v in raw.items()}


def method_key(method: str | Mapping | MethodSpec) -> str:
    """The canonical key of a method written any way (options in any order, or a mapping)."""
    return method_spec(method).name


def method_spec(method: str | Mapping | MethodSpec) -> MethodSpec:
    """The resolved settings of a method key or a mapping; bad input: UserError."""
    if isinstance(method, MethodSpec):
        return method
    preset, options = _split(method)
    try:
        return _with_options(PRESETS[preset], key_of(preset, options), options)
    except ValueError as e:
        raise UserError(f"method {_written(method)!r}: {e}") from None


def _written(method: str | Mapping) -> str:
    return method if isinstance(method, str) else "+".join(f"{k}={v}" for k, v in method.items())


def uses_anchors(method: str | Mapping | MethodSpec) -> bool:
    """Whether a method's interface is relative to an anchor set (PS and its variants)."""
    return method_spec(method).uses_anchors


def reanchoring_problem(method: str, translations: tuple[str, ...]) -> str | None:
    """Why a method's stitches cannot be re-anchored (``anchors@<fit>`` among its translations:
    :mod:`ps_ray.stitching.outcomes`), or None."""
    anchored = [t for t in translations if t.startswith("anchors@")]
    if not anchored or uses_anchors(method):
        return None
    with_one = ", ".join(name for name in PRESETS if uses_anchors(name))
    return (
        f"{anchored[0]} re-anchors a relative projection, and {method} has none; methods with one: {with_one}"
    )


def table_order(label: str) -> tuple[int, str, str]:
    """Sort key for tables: the menu's order, each preset's variants after it, and a translated
    stitch (``<method>+<translation>``, a part without ``=``) right after its method."""
    parts = label.split("+")
    method = "+".join([parts[0], *(p for p in parts[1:] if "=" in p)])
    translation = "+".join(p for p in parts[1:] if "=" not in p)
    return (list(PRESETS).index(parts[0]) if parts[0] in PRESETS else len(PRESETS), method, translation)


# -- the resolved method in a policy file -------------------------------------------------------------
def spec_to_dict(spec: MethodSpec) -> dict[str, Any]:
    return dataclasses.asdict(spec)


def spec_from_dict(data: Mapping[str, Any]) -> MethodSpec:
    """The inverse of :func:`spec_to_dict`; a malformed record raises ValueError naming the problem."""
    try:
        data = dict(data)
        relative, consolidate = data.pop("relative"), data.pop("consolidate")
        return MethodSpec(
            relative=None if relative is None else RelativeSpec(**relative),
            consolidate=None if consolidate is None else ConsolidateSpec(**consolidate),
            **data,
        )
    except (KeyError, TypeError, AttributeError) as e:
        raise ValueError(f"malformed method record ({e})") from None


def spec_json(spec: MethodSpec) -> str:
    return json.dumps(spec_to_dict(spec), sort_keys=True)
