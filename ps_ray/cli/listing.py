"""`ps-ray list`: what a sweep or a command may name (robots, tasks, methods, latent translations)
and the sweeps shipped with ps_ray, one line each, read from the registries themselves."""

from __future__ import annotations

import dataclasses
import re
from pathlib import Path

SWEEPS_DIR = Path(__file__).parents[2] / "sweeps"  # a checkout's shipped sweeps
FAMILIES = {  # what each task family asks, by its class
    "Reach": "move the end effector to a goal point",
    "Push": "push the object along the table to a goal",
    "Pick": "pick the object up and carry it to a goal in the air",
    "Markers": "reach the one of two markers the task names (the transfer family)",
    "PushMarkers": "push the object to the one of two markers the task names (the transfer family)",
}


def listing(sweeps_dir: Path = SWEEPS_DIR) -> list[str]:
    from ps_ray.envs.robots import ROBOTS, RobotSpec
    from ps_ray.envs.tasks import TASKS
    from ps_ray.specs.methods import PRESETS
    from ps_ray.specs.names import TRANSLATION_CHOICES

    lines = ["robots (a sweep's robots:, --robot):"]
    for name, spec in ROBOTS.items():
        lines.append(f"  {name:<16} {_robot(spec, RobotSpec())}")
    lines.append("tasks (a sweep's tasks:, --task):")
    for name, (family, preset) in TASKS.items():
        options = ", ".join(f"{k}={v}" for k, v in preset.items() if k != "table_rgba")
        lines.append(f"  {name:<16} {FAMILIES[family.__name__]}" + (f" ({options})" if options else ""))
    lines.append("methods (a sweep's methods:, --method; options as <method>+key=value, docs/methods.md):")
    for name, spec in PRESETS.items():
        lines.append(f"  {name:<16} {_method(spec)}")
    lines.append("translations (zero_shot.translate:, ps-ray stitch --translate):")
    lines.append("  " + ", ".join(TRANSLATION_CHOICES))
    shipped = sorted(sweeps_dir.glob("*.yaml")) if sweeps_dir.is_dir() else []
    if shipped:
        lines.append(f"sweeps ({sweeps_dir}; price one with ps-ray run FILE --check):")
        lines += [f"  {path.name:<28} {_headline(path)}" for path in shipped]
    return lines


def _robot(spec, default) -> str:
    changed = [f for f in dataclasses.fields(spec) if getattr(spec, f.name) != getattr(default, f.name)]
    parts = []
    for field in changed:
        value = getattr(spec, field.name)
        if field.name == "locked_joints":
            parts.append("joint " + ", ".join(str(j + 1) for j in value) + " locked")
        elif field.name == "mount":
            parts.append(f"mounted at {value:g} degrees about the workspace centre")
        else:
            parts.append(f"{field.name} {value}")
    return "the Franka Panda" + (": " + "; ".join(parts) if parts else ", as in the paper")


def _method(spec) -> str:
    cut = "one MLP cut in the middle" if not spec.modular else "task and robot modules"
    cut += ", relative projection onto anchors" if spec.relative is not None else ", raw latent"
    if spec.interface_dim:
        cut += f", interface {spec.interface_dim}"
    if spec.dropout:
        cut += f", dropout {spec.dropout:g}"
    if spec.consolidate is not None:
        cut += ", distilled into the relative interface after training"
    return cut


def _headline(path: Path) -> str:
    """The first sentence of a sweep file's header comment, on one line."""
    header = []
    for line in path.read_text().splitlines():
        if not line.startswith("#"):
            break
        header.append(line.lstrip("# ").strip())
    text = " ".join(header)
    first = re.split(r"(?<=\?)\s+|[.:;]\s+(?=[A-Z`])", text, maxsplit=1)[0].rstrip(".:;")
    return first if len(first) <= 110 else first[:107].rstrip() + "..."


def cmd_list(args) -> int:
    """`ps-ray list`."""
    print("\n".join(listing()))
    return 0
