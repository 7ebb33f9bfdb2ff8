"""A stitched pair as one record, :class:`StitchedPair`, with its sources, target env and controls
(the zero-shot stage's plan makes them: :mod:`ps_ray.plan.zero_shot`). The zero-shot trials'
configs (:meth:`StitchedPair.to_dict`), the rows of ``zero_shot.csv`` (:meth:`StitchedPair.to_row`),
few-shot's starts and the report's clips are this one record; few-shot and the clips read it back
from the table (:func:`ps_ray.stitching.pair_table.pairs_from_table`).

Ray- and torch-free at import: the report reads the table through it."""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

from ps_ray.specs.modes import Pairing
from ps_ray.specs.names import CONTROL_ROLES, EnvPart, Translation, parse_spec_text, plain_json
from ps_ray.specs.titles import env_title, title

# fields that are a robot or task (an EnvPart; its text in a row)
ENV_FIELDS = ("robot", "task", "task_from_robot", "robot_from_robot", "robot_from_task")
# a pair's fields as MLflow params and as they were before the record carried paths and envs:
# a run's params must not change (the tracker refuses a run whose params differ)
# the files a row names: the two sources' and each control's
PATH_FIELDS = ("task_from_path", "robot_from_path", *(f"{role}_path" for role in CONTROL_ROLES))
# the method shown for the pairs of co-trained grids (ps_ray.pipeline.grid): "ablation co-trained"
CO_TRAINED = "co-trained"
SHOWN = ("method", "translation", "pairing", "seed", "robot_seed", "label", "task_from", "robot_from")


@dataclass(frozen=True)
class Control:
    """An unstitched policy scored beside a pair (:func:`ps_ray.stitching.matrix.controls`)."""

    source: str  # its zoo key
    path: str  # its policy file


@dataclass(frozen=True)
class StitchedPair:
    """One stitched pair: the task module of ``task_from`` with the robot module of
    ``robot_from``, run on (``robot``, ``task``), with its controls by role."""

    key: str  # zero_shot/<method>/<label>/<seed or seed x robot_seed>
    method: str  # <method>+<translation> for a translated stitch
    translation: Translation | Literal[""]  # "" for none
    pairing: str  # same_seed or cross_seed
    seed: int  # the task module's
    robot_seed: int  # the robot module's
    label: str
    task_from: str  # zoo keys and policy files of the two sources
    robot_from: str
    task_from_path: str
    robot_from_path: str
    robot: EnvPart  # the target env
    task: EnvPart
    task_from_robot: EnvPart  # the sources' own envs: the task source ran (task_from_robot, task)
    robot_from_robot: EnvPart
    robot_from_task: EnvPart
    controls: Mapping[str, Control]

    def __post_init__(self) -> None:
        for name in ENV_FIELDS:
            object.__setattr__(self, name, EnvPart(getattr(self, name)))
        if self.translation:
            object.__setattr__(self, "translation", Translation(self.translation))

    @property
    def sources(self) -> tuple[tuple[str, EnvPart, EnvPart], tuple[str, EnvPart, EnvPart]]:
        """The task source and the robot source, each as (policy file, its robot, its task)."""
        return (
            (self.task_from_path, self.task_from_robot, self.task),
            (self.robot_from_path, self.robot_from_robot, self.robot_from_task),
        )

    @property
    def fit_tasks(self) -> tuple[EnvPart, EnvPart]:
        """The tasks a latent translation is fit on: the task source's and the robot source's."""
        return self.task, self.robot_from_task

    @property
    def title(self) -> str:
        """Its MLflow run name (:mod:`ps_ray.specs.titles`): the target env, the method, the seed
        (``431x432`` across runs), then the two sources' cells: ``panda/reach_red ·
        ablation+affine@outcome · 431 · t: panda_far/reach_red, r: panda/reach_blue``."""
        seeds = self.seed if self.pairing == Pairing.SAME_SEED else f"{self.seed}x{self.robot_seed}"
        sources = (
            f"t: {env_title(self.task_from_robot, self.task)}, "
            f"r: {env_title(self.robot_from_robot, self.robot_from_task)}"
        )
        co_trained = CO_TRAINED if "/held_out=" in self.key else ""
        return title(env_title(self.robot, self.task), self.method, seeds, co_trained, sources)

    def shown(self) -> dict[str, str]:
        """MLflow params: no paths, no controls; robot and task by short name."""
        return {
            **{k: str(getattr(self, k)) for k in SHOWN},
            "robot": self.robot.short,
            "task": self.task.short,
        }

    def to_dict(self) -> dict[str, Any]:
        """JSON-able, for a Tune config; :meth:`from_dict` gives the record back."""
        return json.loads(json.dumps(dataclasses.asdict(self), default=plain_json))

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> StitchedPair:
        controls = {role: Control(**c) for role, c in data["controls"].items()}
        return cls(**{**data, "controls": controls})

    def to_row(self, root: Path | None = None) -> dict[str, Any]:
        """A flat CSV row: robots and tasks as their text, each control role as its
        source key (``<role>``) and file (``<role>_path``), empty where the role does not apply;
        files inside ``root`` (the sweep folder) relative to it, so that a sweep folder copied
        elsewhere (``ray rsync-down``) still finds them."""
        row = {f.name: getattr(self, f.name) for f in dataclasses.fields(self) if f.name != "controls"}
        row.update({k: row[k].text for k in ENV_FIELDS})
        for role in CONTROL_ROLES:
            control = self.controls.get(role)
            row[role], row[f"{role}_path"] = (control.source, control.path) if control else ("", "")
        for key in PATH_FIELDS:
            if row[key] and root is not None and Path(row[key]).is_relative_to(root):
                row[key] = str(Path(row[key]).relative_to(root))
        return row

    @classmethod
    def from_row(cls, row: Mapping[str, Any], root: Path | None = None) -> StitchedPair:
        """The record of a :meth:`to_row` row, also as read back from CSV (every cell text);
        relative files are taken inside ``root``."""
        names = [f.name for f in dataclasses.fields(cls) if f.name != "controls"]
        text = {k: _text(row[k]) for k in (*names, *PATH_FIELDS)}
        for key in PATH_FIELDS if root is not None else ():
            if text[key] and not Path(text[key]).is_absolute():
                text[key] = str(Path(root) / text[key])
        controls = {
            role: Control(_text(row[role]), text[f"{role}_path"])
            for role in CONTROL_ROLES
            if _text(row[role])
        }
        return cls(
            **{
                **{k: text[k] for k in names},
                **{k: parse_spec_text(text[k]) for k in ENV_FIELDS},
                "seed": int(text["seed"]),
                "robot_seed": int(text["robot_seed"]),
                "controls": controls,
            }
        )


def _text(value: Any) -> str:
    """A cell as text; a missing one (None, NaN) empty."""
    return "" if value is None or value != value else str(value)
