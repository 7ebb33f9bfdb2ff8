"""Every file format ps_ray writes, with an id of one style: ``ps_ray.<name>/<version>``.

A writer puts :attr:`FileFormat.id` in its file; a reader asks :meth:`FileFormat.version_of`
for the version a file's id names, which also knows the ids an earlier ps_ray spelt another way,
so old spellings are resolved here and nowhere else. A version newer than this code's, or an id
of another format, is refused by the reader in one line; an older version goes through the one
upgrade function beside its reader: ``ps_ray.store.signature.upgrade`` (policy files 1 -> 2),
``ps_ray.rllib.sac_her.read_learner_file`` and ``ps_ray.store.checkpoint.progress``
(checkpoints), ``ps_ray.stitching.pair_table.upgrade``
(zero-shot tables).
tests/data/formats holds a golden file of each format and version, read by today's readers.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field


@dataclass(frozen=True)
class FileFormat:
    name: str  # ps_ray.<name>
    version: int  # the version this code writes (and the newest it reads)
    spellings: Mapping[str, int] = field(default_factory=dict)  # ids of an earlier ps_ray -> version

    @property
    def id(self) -> str:
        return f"{self.name}/{self.version}"

    @property
    def readable(self) -> tuple[str, ...]:
        """The ids of the versions this code reads, oldest first."""
        return tuple(f"{self.name}/{v}" for v in range(1, self.version + 1))

    def version_of(self, found: object) -> int | None:
        """The version a file's id names; None for an id of another format (or none)."""
        if not isinstance(found, str):
            return None
        if found in self.spellings:
            return self.spellings[found]
        head, _, number = found.rpartition("/")
        return int(number) if head == self.name and number.isdigit() and int(number) >= 1 else None

    def reads(self, found: object) -> bool:
        """Whether this code reads a file of id ``found`` (this format, not a newer version)."""
        version = self.version_of(found)
        return version is not None and version <= self.version


def id_in(meta: Mapping[str, object]) -> object:
    """The format id a file's JSON metadata holds: its ``format``, joined to its ``version`` where
    an earlier ps_ray wrote them apart (anchor sets)."""
    found = meta.get("format")
    return f"{found}/{meta['version']}" if "version" in meta else found


# version 2: the learner file holds torch's generator state, progress.json the best evaluation and
# the consolidation (a version-1 checkpoint's may not)
CHECKPOINT = FileFormat("ps_ray.checkpoint", 2, {"ps_ray-checkpoint-1": 1})
REPLAY_SEGMENTS = FileFormat("ps_ray.replay_segments", 1, {"ps_ray-replay-segments-1": 1})
HINDSIGHT_REPLAY = FileFormat("ps_ray.hindsight_replay", 1, {"ps_ray.HindsightReplay/1": 1})
# an earlier ps_ray wrote the anchor set's name and version as two fields: id_in joins them
ANCHOR_SET = FileFormat("ps_ray.anchor_set", 1)
POLICY = FileFormat("ps_ray.policy", 2)
EXAMPLE_ZOO = FileFormat("ps_ray.example_zoo", 1)
# zero_shot.csv names it in a ``format`` column; a table without one is of version 1; version 3
# adds the told robot source's success (ps_ray.stitching.told)
ZERO_SHOT_TABLE = FileFormat("ps_ray.zero_shot_table", 3)
# a zero-shot stage's kept chance level and floor: a file of another version is measured again
CHANCE = FileFormat("ps_ray.chance", 1)
FORMATS = (
    CHECKPOINT,
    REPLAY_SEGMENTS,
    HINDSIGHT_REPLAY,
    ANCHOR_SET,
    POLICY,
    EXAMPLE_ZOO,
    ZERO_SHOT_TABLE,
    CHANCE,
)
