"""The house's boundaries, read from its imports: no circle, analysis reads a sweep only through the
store, and the light commands load neither Ray nor torch."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

PACKAGE = Path(__file__).parents[1] / "ps_ray"
REPO = PACKAGE.parent


def _module(path: Path) -> str:
    parts = path.relative_to(REPO).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _imports(path: Path, modules: set[str]) -> set[str]:
    """Every ps_ray module ``path`` imports, at the top, inside a function or under ``if
    TYPE_CHECKING:`` (an import for annotations only still ties the two modules together)."""
    tree = ast.parse(path.read_text())
    package = _module(path) if path.name == "__init__.py" else _module(path).rpartition(".")[0]
    found = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:  # relative: "from .sim import Sim" inside ps_ray.envs
                parent = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join([*parent, base] if base else parent)
            names = [f"{base}.{alias.name}" for alias in node.names]
        else:
            continue
        for name in names:
            while name and name not in modules:  # "from ps_ray.x import func" -> ps_ray.x
                name = name.rpartition(".")[0]
            if name.startswith("ps_ray"):
                found.add(name)
    return found


def _graph() -> dict[str, set[str]]:
    paths = {_module(p): p for p in PACKAGE.rglob("*.py")}
    graph = {}
    for name, path in paths.items():
        # a module importing its own package's __init__ (or a parent's) is not a cycle
        graph[name] = {m for m in _imports(path, set(paths)) if m != name and not name.startswith(m + ".")}
    return graph


def _cycle(graph: dict[str, set[str]]) -> list[str] | None:
    state: dict[str, int] = {}  # 1: on the current path, 2: done
    path: list[str] = []

    def visit(node: str) -> list[str] | None:
        state[node] = 1
        path.append(node)
        for nxt in sorted(graph.get(node, ())):
            if state.get(nxt) == 1:
                return path[path.index(nxt) :] + [nxt]
            if nxt not in state and (found := visit(nxt)):
                return found
        path.pop()
        state[node] = 2
        return None

    for node in sorted(graph):
        if node not in state and (found := visit(node)):
            return found
    return None


def test_no_module_of_the_package_imports_itself_in_a_circle():
    graph = _graph()
    assert len(graph) > 50
    assert _cycle(graph) is None, " -> ".join(_cycle(graph))
    # the check finds one: a planted back edge closes a circle
    planted = {**graph, "ps_ray.specs.methods": graph["ps_ray.specs.methods"] | {"ps_ray.specs.train"}}
    assert _cycle(planted) is not None


def test_analysis_and_the_store_never_import_the_tune_stages():
    for name, imported in _graph().items():
        if name.startswith(("ps_ray.analysis", "ps_ray.store")):
            stages = sorted(m for m in imported if m.startswith("ps_ray.pipeline"))
            assert not stages, f"{name} imports {stages}"


def test_no_stage_runner_imports_another_stage():
    """A stage's runner (pipeline/run.py RUNNERS) reaches what stages share through modules of
    their own (the Tune runners, the anchor sets, the stage's folder and store), never through
    another stage, so a stage can be read, changed or removed alone."""
    from ps_ray.pipeline.run import RUNNERS

    runners = {f"ps_ray.pipeline.{'sweep' if s == 'train' else s}" for s in RUNNERS if s != "report"}
    graph = _graph()
    assert runners <= set(graph), runners - set(graph)
    for name in sorted(runners):
        assert not graph[name] & (runners - {name}), f"{name} imports {sorted(graph[name] & runners)}"


def test_no_module_is_over_400_lines():
    long = {p.name: n for p in PACKAGE.rglob("*.py") if (n := len(p.read_text().splitlines())) > 400}
    assert not long, long


def _loaded_after(code: str, names: tuple[str, ...] = ("ray", "torch")) -> set[str]:
    probe = code + f"\nimport sys; print(' '.join(m for m in {names!r} if m in sys.modules))"
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, cwd=REPO, check=True)
    return set(out.stdout.split("\n")[-2].split())


@pytest.mark.e2e
def test_the_report_module_and_a_sweep_check_load_neither_ray_nor_torch():
    assert _loaded_after("import ps_ray.analysis.report") == set()
    check = "from ps_ray import cli\nassert cli.main(['sweep', 'sweeps/transfer.yaml', '--check']) == 0"
    assert _loaded_after(check) == set()
    assert _loaded_after("import ps_ray.nets.policy_file") == {"torch"}  # the probe sees what is loaded
    # the driver's check of the files a sweep starts from reads their signatures, builds no nets
    start = "ps_ray/stitching/example/oracle.safetensors"
    sweep = (
        "from ps_ray.specs.sweep import SweepSpec\nfrom ps_ray.pipeline.sweep import check_inputs\n"
        "spec = SweepSpec.from_mapping({'name': 's', 'methods': ['ablation'], 'robots': ['panda_far'], "
        f"'tasks': ['reach_blue'], 'seeds': [1], 'train': {{'init_policy': '{start}', 'hidden': 128}}}})\n"
        "check_inputs(spec)"
    )
    assert _loaded_after(sweep) == set()


@pytest.mark.e2e
def test_the_update_benchmark_runs_where_only_torch_is_installed(tmp_path):
    """A GPU host without PyBullet or Ray (docs/cost.md, "A GPU update, measured") times the update
    with the widths given, and the nets it saves are policy files a CPU host loads."""
    from safetensors import safe_open

    from ps_ray.nets.policy_file import load_policy

    args = ["--dims", "15,8,7", "--methods", "ps", "--rounds", "1", "--updates", "2", "--save", str(tmp_path)]
    code = f"from ps_ray.bench import update\nupdate.main({args!r})"
    assert _loaded_after(code, ("ray", "torch", "pybullet", "gymnasium", "mlflow")) == {"torch"}
    # the GPU host's one call (`python -m ps_ray.bench.gpu`, docs/cost.md "The GPU check") likewise
    assert (
        _loaded_after("import ps_ray.bench.gpu", ("ray", "pybullet", "gymnasium", "mlflow", "sklearn"))
        == set()
    )
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ablation_cpu.safetensors", "ps_cpu.safetensors"]
    nets, signature = load_policy(tmp_path / "ps_cpu.safetensors")
    widths = (signature.task_dim, signature.robot_dim, signature.action_dim)
    assert (signature.method, widths) == ("ps", (15, 8, 7))
    assert nets.actor.anchors.shape == (128, 15)
    with safe_open(str(tmp_path / "ps_cpu.safetensors"), "pt") as f:
        assert f.metadata()["written_on"] == "cpu"


def test_every_module_but_the_errors_lives_in_the_package_of_its_floor():
    assert sorted(p.name for p in PACKAGE.glob("*.py")) == ["__init__.py", "errors.py"]


# The floors of the house, from the ground up (docs/reference.md, "Package layout"): a module may
# import its own package and the floors below, never a floor above or a package beside it.
FLOORS = {
    "errors": 0,
    "envs": 1,
    "specs": 2,
    "store": 3,
    "data": 4,
    "nets": 5,
    "stitching": 6,
    "plan": 7,
    "analysis": 8,
    "rllib": 8,
    "pipeline": 9,
    "cli": 10,
    "bench": 11,
}


def _package(module: str) -> str:
    return module.split(".")[1] if module.count(".") else ""


def _upward(graph: dict[str, set[str]]) -> list[str]:
    return sorted(
        f"{name} -> {target}"
        for name, imported in graph.items()
        for target in imported
        if _package(name) and _package(target) and _package(name) != _package(target)
        if FLOORS[_package(target)] >= FLOORS[_package(name)]
    )


def test_every_import_points_down_the_floors():
    graph = _graph()
    assert not _upward(graph), _upward(graph)
    assert set(FLOORS) == {_package(m) for m in graph if _package(m)}
    # the check finds one: the envs importing the store (a floor above) is refused
    planted = {**graph, "ps_ray.envs.urdf": graph["ps_ray.envs.urdf"] | {"ps_ray.store.atomic"}}
    assert _upward(planted) == ["ps_ray.envs.urdf -> ps_ray.store.atomic"]
