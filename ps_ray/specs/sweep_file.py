"""A sweep YAML file as one mapping: strict YAML, a ``base`` file merged under it, ``--set``
overrides on top (docs/guide.md, "Sweeps that share a base").

A sweep may name a base (``base: markers.yaml``, relative to the file) and give only the keys that
change: mappings merge key by key at every depth, anything else (a list, a number, a string)
replaces the base's value. A base may name its own base. Malformed YAML, a key given twice in one
mapping, a missing or circular base and a bad ``--set`` are one line naming the file; unknown keys
and bad values are refused by :class:`ps_ray.specs.sweep.SweepSpec` as for any sweep.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from ps_ray.specs.train import SpecError

BASE_KEY = "base"


def strict_yaml(text: str) -> Any:
    """``yaml.safe_load`` that refuses a key given twice in one mapping (PyYAML keeps the last)."""
    import yaml

    class Strict(yaml.SafeLoader):
        def construct_mapping(self, node, deep=False):
            seen = set()
            for key_node, _ in node.value:
                key = self.construct_object(key_node, deep=True)
                if key in seen:
                    raise yaml.constructor.ConstructorError(
                        problem=f"duplicate key {key!r} (a key may be given once)",
                        problem_mark=key_node.start_mark,
                    )
                seen.add(key)
            return super().construct_mapping(node, deep)

    return yaml.load(text, Loader=Strict)  # noqa: S506 (a SafeLoader)


def merged(base: Mapping[str, Any], override: Mapping[str, Any]) -> dict[str, Any]:
    """``override`` over ``base``: mappings merge key by key, any other value replaces."""
    out = dict(base)
    for key, value in override.items():
        if isinstance(value, Mapping) and isinstance(out.get(key), Mapping):
            out[key] = merged(out[key], value)
        else:
            out[key] = value
    return out


def read_file(path: Path) -> Any:
    """One YAML file, strictly: one line naming the file for anything unreadable."""
    import yaml

    try:
        return strict_yaml(path.read_text())
    except FileNotFoundError:
        raise SpecError(f"{path}: no such sweep file") from None
    except IsADirectoryError:
        raise SpecError(f"{path}: is a folder, not a sweep file") from None
    except UnicodeDecodeError as e:
        raise SpecError(f"{path}: not a UTF-8 text file (byte {e.start}); a sweep is YAML text") from None
    except yaml.YAMLError as e:
        mark = getattr(e, "problem_mark", None)
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark else ""
        raise SpecError(f"{path}: malformed YAML{where}: {getattr(e, 'problem', e)}") from None


def header(path: Path) -> str:
    """The comment lines that open a sweep file, without their ``#``: what the sweep is for."""
    lines = []
    for line in path.read_text(errors="replace").splitlines():
        if not line.startswith("#"):
            break
        lines.append(line[1:].removeprefix(" "))
    return "\n".join(lines).strip()


def read_sweep(path: Path, sets: Sequence[str] = (), _seen: tuple[Path, ...] = ()) -> Any:
    """The sweep file's mapping with its bases merged under it and ``sets`` (``key.sub=value``,
    the value read as YAML) over it."""
    data = read_file(path)
    if isinstance(data, Mapping) and BASE_KEY in data:
        name = data[BASE_KEY]
        if not isinstance(name, str) or not name:
            raise SpecError(f"{path}: base must be the path of a sweep file, got {name!r}")
        base_path = (path.parent / name).resolve()
        if base_path in (*_seen, path.resolve()):
            raise SpecError(f"{path}: base {name!r} names a file already in its chain of bases")
        base = read_sweep(base_path, (), (*_seen, path.resolve()))
        if not isinstance(base, Mapping):
            raise SpecError(f"{base_path}: a base sweep file must be a mapping of keys")
        data = merged(base, {k: v for k, v in data.items() if k != BASE_KEY})
    for text in sets:
        data = merged(data if isinstance(data, Mapping) else {}, parse_set(text))
    return data


def parse_set(text: str) -> dict[str, Any]:
    """``zero_shot.episodes=10`` -> ``{"zero_shot": {"episodes": 10}}`` (the value read as YAML)."""
    import yaml

    key, sep, value = text.partition("=")
    parts = key.split(".")
    if not sep or not all(p.strip() for p in parts):
        raise SpecError(f"bad --set {text!r}; write KEY=VALUE, e.g. --set zero_shot.episodes=10")
    try:
        out: Any = strict_yaml(value)
    except yaml.YAMLError:
        raise SpecError(f"bad --set {text!r}: its value is not YAML") from None
    for part in reversed(parts):
        out = {part.strip(): out}
    return out
