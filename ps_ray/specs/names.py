"""Names: a robot or task as one normalised type (:class:`EnvPart`), as an exact string and as a
short one, and a trial's key (its run folder, MLflow run and zoo entry). The one place that
converts between them."""

from __future__ import annotations

import hashlib
import json
import re
from collections.abc import Iterator, Mapping
from typing import Annotated, Any

from pydantic import BeforeValidator

from ps_ray.errors import UserError
from ps_ray.specs.defaults import INTERFACE_DIM
from ps_ray.specs.engine import Invalid
from ps_ray.specs.modes import AnchorGoals

# How a stitch aligns its interface, by name: a latent translation fitted between the two task
# modules (ps_ray.nets.translation), or "anchors": the task module's relative projection re-anchored
# on task states matched to the robot module's anchors (ps_ray.stitching.outcomes; needs a fit).
# "affine" is ridge-regularised; "affine_lstsq" the plain least-squares fit it replaced
# (ps_ray.nets.translation); "anchors" moves the anchors and adds no map
TRANSLATIONS = ("orthogonal", "affine", "affine_lstsq", "anchors")
LATENT_TRANSLATIONS = TRANSLATIONS[:3]
# What a translation is fitted on, other than the same task states through both task modules
# (ps_ray.stitching.outcomes): scenes matched by the outcome of each task's own policy, the same
# pairs shuffled (a control), or the known correspondence of the marker family (an upper bound).
# Spelt "<translation>@<fit>", e.g. "affine@outcome".
TRANSLATION_FITS = ("outcome", "shuffled", "swapped")
# Re-anchoring may also match a scene by where *both* tasks' sources end in it ("anchors@both"), or
# decode one from those two outcomes by an affine map fitted on the candidate scenes ("anchors@decoded")
CROSSED_FITS = ("both", "decoded")  # fits that read both sources' outcomes in every scene
ANCHOR_FITS = (*TRANSLATION_FITS, *CROSSED_FITS)
# The unstitched controls and the oracle scored beside every stitched pair (ps_ray.stitching.matrix.controls)
CONTROL_ROLES = ("robot_source", "task_source", "oracle")
ANCHOR_GOALS = tuple(AnchorGoals)  # the desired goals of anchor states (ps_ray.data.collect)


# Every valid spelling, in the order error messages list them
TRANSLATION_CHOICES = (
    *LATENT_TRANSLATIONS,
    *(f"{k}@{f}" for k in LATENT_TRANSLATIONS for f in TRANSLATION_FITS),
    *(f"anchors@{f}" for f in ANCHOR_FITS),
)


class Translation(str):
    """A translation as a sweep names it, parsed once: ``kind`` (one of TRANSLATIONS) and ``fit``,
    where its fit states come from ("" the same task states through both task modules, or one of
    ANCHOR_FITS). A str, so that configs, tables and MLflow hold its name; an unknown name is a
    UserError naming the valid choices."""

    kind: str
    fit: str

    def __new__(cls, name: str) -> Translation:
        if isinstance(name, Translation):
            return name
        kind, _, fit = str(name).partition("@")
        if (fit and name not in TRANSLATION_CHOICES) or (not fit and kind not in LATENT_TRANSLATIONS):
            raise UserError(f"unknown translation {name!r}; valid: {', '.join(TRANSLATION_CHOICES)}")
        self = super().__new__(cls, name)
        self.kind, self.fit = kind, fit
        return self

    @property
    def scene_fit(self) -> bool:
        """Whether its fit sets scenes from task inputs or swaps their markers (the marker family
        only): any ``anchors@`` re-anchoring, and ``@swapped``."""
        return self.kind == "anchors" or self.fit == "swapped"


def translations_problem(kinds: Any) -> str | None:
    """What is wrong with a list of translation names (None: nothing)."""
    if not isinstance(kinds, (list, tuple)) or not kinds:
        return f"expected a list of translations, got {kinds!r}; valid: {', '.join(TRANSLATION_CHOICES)}"
    for kind in kinds:
        try:
            Translation(kind if isinstance(kind, str) else repr(kind))
        except UserError as e:
            return str(e)
    return f"duplicate translation in {list(kinds)}" if len(set(kinds)) != len(kinds) else None


class EnvPart(Mapping[str, Any]):
    """A robot or a task as a spec names it: a built-in name, or a mapping of a name and the options
    that override its preset (``{"name": "reach", "goal_region": "q2"}``; a robot mapping may give
    its fields without a name). Specs turn whatever was written into this one type when they load,
    so everything after them handles one thing.

    Immutable and hashable. A mapping holding only a name is that name, and a part equals its own
    spelling, so ``part == "panda"`` and ``{"panda": ...}[part]`` read as written. Its
    :attr:`spelling` is what JSON files hold (trial digests and policy files do not change) and its
    :attr:`text` one exact string (a name, or sorted JSON) for CSV cells and command lines.
    """

    def __init__(self, value: str | Mapping[str, Any]) -> None:
        if isinstance(value, EnvPart):
            items: dict[str, Any] = dict(value._items)
        elif isinstance(value, str):
            items = {"name": value}
        elif isinstance(value, Mapping):
            try:  # a deep copy in JSON's own types: tuples become lists, as in the files
                items = json.loads(json.dumps(dict(value)))
            except (TypeError, ValueError) as e:
                raise UserError(f"robot or task {dict(value)!r} is not plain data ({e})") from None
        else:
            raise UserError(f"a robot or task is a name or a mapping, got {value!r}")
        self._items = items
        only_name = set(items) == {"name"} and isinstance(items["name"], str)
        self.text: str = items["name"] if only_name else json.dumps(items, sort_keys=True)

    @property
    def name(self) -> str | None:
        """The built-in it starts from (None for a robot mapping without a name)."""
        return self._items.get("name")

    @property
    def options(self) -> dict[str, Any]:
        """The settings beside the name."""
        return {k: v for k, v in self._items.items() if k != "name"}

    @property
    def spelling(self) -> str | dict[str, Any]:
        """The name alone, or the mapping (a copy): what a JSON file holds."""
        return self.text if set(self._items) == {"name"} else json.loads(json.dumps(self._items))

    @property
    def short(self) -> str:
        """The name a run folder, a table and a plot show (:func:`short_name`)."""
        return short_name(self)

    def __getitem__(self, key: str) -> Any:
        return self._items[key]

    def __iter__(self) -> Iterator[str]:
        return iter(self._items)

    def __len__(self) -> int:
        return len(self._items)

    def __eq__(self, other: object) -> bool:
        if isinstance(other, (str, Mapping)):
            try:
                return self.text == EnvPart(other).text
            except UserError:
                return False
        return NotImplemented

    def __hash__(self) -> int:
        return hash(self.text)

    def __repr__(self) -> str:
        return f"EnvPart({self.spelling!r})"

    def __str__(self) -> str:
        return self.text


def plain_json(value: Any) -> Any:
    """``json.dumps``'s ``default``: a robot or task as its spelling (specs and records hold them)."""
    if isinstance(value, EnvPart):
        return value.spelling
    raise TypeError(f"{type(value).__name__} is not JSON data")


def spec_text(value: str | Mapping) -> str:
    """A robot or task as one exact string (its name, or its mapping as sorted JSON), to key
    dicts by and to pass on a command line; :func:`parse_spec_text` gives the part back."""
    return EnvPart(value).text


def parse_spec_text(text: str) -> EnvPart:
    """The robot or task a :func:`spec_text` string (or a ``--robot/--task`` flag) stands for."""
    if not text.strip().startswith("{"):
        return EnvPart(text)
    try:
        return EnvPart(json.loads(text))
    except json.JSONDecodeError as e:
        raise UserError(f"{text!r} is neither a name nor a JSON mapping ({e})") from None


def short_name(value: Any, limit: int = 64) -> str:
    """A robot/task: its name; a mapping ``{"name": base, ...}`` as ``base{json of the rest}``,
    or ``base#<hash>`` when that is longer than ``limit`` characters."""
    if not isinstance(value, Mapping):
        return str(value)
    rest = {k: v for k, v in value.items() if k != "name"}
    base = str(value.get("name", "custom"))
    if not rest:
        return base
    text = json.dumps(rest, sort_keys=True, separators=(",", ":"), default=str)
    if len(base) + len(text) <= limit:
        return base + text
    return f"{base}#{hashlib.sha256(text.encode()).hexdigest()[:8]}"


KEY_FIELDS = ("method", "robot", "task", "seed")


def trial_key(spec: Mapping[str, Any]) -> str:
    """``method/robot/task/seed`` (``method/<env>/seed`` for a gymnasium env given by id), plus
    ``/i<dim>`` for a non-default interface dim: the name of a trial's run directory, MLflow run
    and zoo entry."""
    env = spec.get("env")
    parts = [spec.get("method"), env.rpartition(":")[2].replace("/", "-"), spec.get("seed")] if env else None
    key = "/".join(map(str, parts)) if parts else "/".join(short_name(spec.get(k)) for k in KEY_FIELDS)
    dim = spec.get("interface_dim", INTERFACE_DIM)
    return key if dim == INTERFACE_DIM else f"{key}/i{dim}"


_VARIANT = re.compile(r"(\w+)(\{[^{}]*\})")


def readable(text: str) -> str:
    """``text`` with every robot or task variant written as a reader would: a string option by
    its value, another as ``key=value`` (``reach{"goal_region":"q1"}`` -> ``reach q1``,
    ``push{"friction":0.1}`` -> ``push friction=0.1``). For tables, plots and captions only: keys,
    file names and CSV cells keep the exact :func:`short_name`."""

    def one(match: re.Match) -> str:
        try:
            options = json.loads(match.group(2))
        except json.JSONDecodeError:
            return match.group(0)
        words = [v if isinstance(v, str) else f"{k}={json.dumps(v)}" for k, v in options.items()]
        return " ".join([match.group(1), *words])

    return _VARIANT.sub(one, text)


def env_part(value: Any) -> EnvPart:
    """A robot or task as a spec field reads it (a name or a mapping): the one type :class:`EnvPart`."""
    if not isinstance(value, (str, Mapping)):
        raise Invalid("must be a name or a mapping")
    return EnvPart(value)


Part = Annotated[EnvPart, BeforeValidator(env_part)]  # a spec field holding a robot or a task
