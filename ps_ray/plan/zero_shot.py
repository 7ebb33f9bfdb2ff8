"""The zero-shot stage's trials: the sweep's stitching matrix, one :class:`StitchedPair` per
stitched pair (and per latent translation), with its sources, target env and controls."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

from ps_ray.errors import UserError
from ps_ray.specs import reset_seeds
from ps_ray.specs.modes import Pairing
from ps_ray.specs.stage_settings import ZeroShotSpec
from ps_ray.specs.sweep import SweepSpec, seed_pairs
from ps_ray.stitching.matrix import combos, controls
from ps_ray.stitching.pairs import CO_TRAINED, Control, StitchedPair
from ps_ray.stitching.zoo import ModuleZoo


def plan(spec: SweepSpec, zoo: ModuleZoo, settings: ZeroShotSpec | None = None) -> list[StitchedPair]:
    """The stage's pairs: of ``settings.methods`` (default: the sweep's), in the pairing it names,
    each untranslated and then once per translation it names for the method."""
    settings = settings or spec.zero_shot
    spec = dataclasses.replace(spec, zero_shot=settings)  # the translations the settings name
    return matrix(spec, zoo, list(settings.methods) or None, translate=True, pairing=settings.pairs)


def matrix(
    spec: SweepSpec,
    zoo: ModuleZoo,
    methods: list[str] | None = None,
    translate: bool = False,
    pairing: str = "same_seed",
) -> list[StitchedPair]:
    """Every stitched pair of the zoo's modules of ``methods`` (``pairing``: see :func:`seed_pairs`),
    with the zoo keys and files of its controls (:func:`ps_ray.stitching.matrix.controls`); a
    co-trained grid's pairs as their own rows (``<method> co-trained``); with ``translate``, also
    one per latent translation that ``spec.zero_shot.translate`` names for the method (its method
    shown as ``<method>+<translation>``, right after the untranslated pair)."""
    out = []
    for method, grid in ((m, g) for m in methods or spec.methods for g in ("", *zoo.grids(m))):
        kinds = ("", *spec.zero_shot.translations(method)) if translate else ("",)
        shown = f"{method} {CO_TRAINED}" if grid else method
        for kind_of_pair, seed, robot_seed in seed_pairs(spec.seeds, pairing):
            for combo in combos(zoo, method, seed, robot_seed=robot_seed, grid=grid):
                seeds = str(seed) if kind_of_pair == Pairing.SAME_SEED else f"{seed}x{robot_seed}"
                t, r = combo.task_from, combo.robot_from
                found = {role: Control(str(e.key), str(e.path)) for role, e in controls(zoo, combo).items()}
                for kind in kinds:
                    name = f"{shown}+{kind}" if kind else shown
                    out.append(
                        StitchedPair(
                            key=f"zero_shot/{name}/{combo.label}/{seeds}"
                            + (f"/held_out={grid}" if grid else ""),
                            method=name,
                            translation=kind,
                            pairing=kind_of_pair,
                            seed=seed,
                            robot_seed=robot_seed,
                            label=combo.label,
                            task_from=str(t.key),
                            robot_from=str(r.key),
                            task_from_path=str(t.path),
                            robot_from_path=str(r.path),
                            robot=combo.robot,
                            task=combo.task,
                            task_from_robot=t.robot,
                            robot_from_robot=r.robot,
                            robot_from_task=r.task,
                            controls=found,
                        )
                    )
    return out


def alone_pairs(spec: SweepSpec, zoo: ModuleZoo, methods: list[str] | None = None) -> list[StitchedPair]:
    """The same-seed pairs without a translation of sources trained alone (no grid's), of
    ``methods`` (default: the sweep's), in :func:`matrix` order: the pairs few-shot starts from."""
    methods = list(methods or spec.methods)
    return [p for p in matrix(spec, zoo, methods) if p.method in methods]


def evaluated_pairs(
    spec: SweepSpec,
    table: list[StitchedPair] | None,
    zoo: Callable[[], ModuleZoo],
    methods: list[str] | None = None,
) -> list[StitchedPair]:
    """:func:`alone_pairs` as the zero-shot stage ran them: taken from ``table`` (its
    ``zero_shot.csv``, read by the caller: :func:`ps_ray.stitching.pair_table.pairs_from_table`; None:
    no usable table) for the methods it evaluated, planned on ``zoo()`` (called only then) for the
    others (a sweep that skips zero-shot)."""
    methods = list(methods or spec.methods)
    by_method = {
        m: [p for p in table or [] if p.method == m and p.pairing == Pairing.SAME_SEED and not p.translation]
        for m in methods
    }
    missing = [m for m in methods if not by_method[m]]
    if missing:
        built = alone_pairs(spec, zoo(), missing)
        by_method.update({m: [p for p in built if p.method == m] for m in missing})
    return [pair for m in methods for pair in by_method[m]]


@dataclass(frozen=True)
class Episodes:
    """``evaluate``'s fixed episodes: how many, how often each, and the first reset seed."""

    episodes: int
    repeats: int
    seed: int

    def kwargs(self) -> dict[str, int]:
        return dataclasses.asdict(self)


@dataclass(frozen=True)
class FitSettings:
    """Where a translation's fit states come from: reset states per goal quadrant (a fit without
    ``@``), or the sources' ``scenes`` rolled-out outcomes matched at ``points`` reference points
    (k-means ``seed``), cached in ``cache``; ``fit_seed``: the first reset seed of the fit states."""

    states_per_quadrant: int
    scenes: int
    points: int
    cache: str
    seed: int
    fit_seed: int

    @classmethod
    def of(cls, settings: ZeroShotSpec, cache: str) -> FitSettings:
        return cls(
            states_per_quadrant=settings.fit_states_per_quadrant,
            scenes=settings.outcome_scenes,
            points=settings.outcome_points,
            cache=cache,
            seed=settings.seed,
            fit_seed=reset_seeds.fixed("fit", settings.seed),
        )


@dataclass(frozen=True)
class ZeroShotBatch:
    """One zero-shot Tune trial: ``pairs`` scored one after another, each on its own block of the
    stage's ``stream`` (:func:`pair_episodes`) beside the ``chance`` figures of its target env
    (:func:`target_key`), translations fitted as ``fit`` says. A Tune config holds it as plain
    JSON: the batch's pairs under one grid key, the rest shared by every batch (:meth:`shared`)."""

    pairs: tuple[StitchedPair, ...]
    stream: Episodes
    fit: FitSettings
    chance: Mapping[str, dict]

    @staticmethod
    def shared(stream: Episodes, fit: FitSettings, chance: Mapping[str, dict]) -> dict[str, Any]:
        return {"stream": stream.kwargs(), "fit": dataclasses.asdict(fit), "chance": dict(chance)}

    @classmethod
    def from_config(cls, config: Mapping[str, Any]) -> ZeroShotBatch:
        return cls(
            pairs=tuple(StitchedPair.from_dict(p) for p in config["batch"]),
            stream=Episodes(**config["stream"]),
            fit=FitSettings(**config["fit"]),
            chance=config["chance"],
        )

    def episodes(self, pair: StitchedPair) -> Episodes:
        return pair_episodes(pair, self.stream)

    def chance_of(self, pair: StitchedPair) -> dict:
        return self.chance[target_key(pair, self.episodes(pair))]


def pair_episodes(pair: StitchedPair, stream: Episodes) -> Episodes:
    """A pair's episodes, given the stage's ``stream`` (its episodes, repeats and ``seed`` setting):
    the training seed's own block of the zero-shot stream
    (:func:`ps_ray.specs.reset_seeds.fixed_for_run`), so that each seed's pairs, controls, chance
    and floor share their scenes and seeds see different ones. A cross-seed pair takes the block
    of its task module's seed (``pair.seed``)."""
    first = reset_seeds.fixed_for_run("zero_shot", stream.seed, pair.seed, stream.episodes * stream.repeats)
    return dataclasses.replace(stream, seed=first)


def stream_of(settings: ZeroShotSpec) -> Episodes:
    """The stage's episodes, repeats and ``seed`` setting, from which each pair's block is taken."""
    return Episodes(settings.episodes, settings.repeats, settings.seed)


def target_key(pair: StitchedPair, episodes: Episodes) -> str:
    """The pair's target env and first reset seed, as the chance figures are keyed."""
    return f"{pair.robot.text} {pair.task.text} @{episodes.seed}"


def check_kept(done: dict[str, dict], trials: list[StitchedPair], settings: ZeroShotSpec) -> None:
    """A resumed matrix keeps only rows scored as this code scores them: on the pair's own
    episodes (:func:`pair_episodes`). Rows of an older ps_ray (every seed on one block of episodes,
    a floor of one draw, ``affine`` by plain least squares) are refused in one line."""
    for pair in trials:
        row = done.get(pair.key)
        if row is None:
            continue
        want = pair_episodes(pair, stream_of(settings)).seed
        if row.get("episodes_seed") != want:
            raise UserError(
                f"{pair.key}: its kept zero-shot row was scored on other episodes (an older ps_ray "
                f"or other settings); run the stage afresh in another storage or sweep name"
            )
