"""`--check` of `ps-ray sweep` and `ps-ray run`: what a sweep would run and what it would cost, for
every stage it names (the trials, then :func:`ps_ray.analysis.cost.project`'s projection on
this machine, on ideal cores and on cluster.yaml's kinds); nothing is run or written."""

from __future__ import annotations

from ps_ray.cli.paths import writable_folder
from ps_ray.specs.sweep import SweepSpec


def print_check(spec: SweepSpec, cores: int) -> int:
    """Print the trials and the projected cost; exit status 0."""
    from ps_ray.analysis.cost import describe, project
    from ps_ray.specs.search import describe as describe_trials
    from ps_ray.store.layout import sweep_layout

    writable_folder(sweep_layout(spec).root)  # what a run would need, refused now; nothing is left
    print("\n".join([*describe_trials(spec.search, spec.named_trials()), *describe(project(spec, cores))]))
    return 0
