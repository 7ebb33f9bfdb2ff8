"""cluster.yaml: validated by Ray's own cluster-launcher code, plus the properties a reviewer checks.

`ray up` runs ``prepare_config`` (merge with the provider's defaults.yaml) and then
``validate_config`` (jsonschema against ``ray/autoscaler/ray-schema.json`` plus Ray's own
cross-field checks) before it touches AWS; both run offline and need no boto3, so the tests
call exactly those two functions. No network, no Ray processes.
"""

from __future__ import annotations

import copy
import re
import shlex
import subprocess
import tomllib
from pathlib import Path

import jsonschema
import pytest
import ray.autoscaler
import yaml
from ray.autoscaler._private.util import prepare_config, validate_config

ROOT = Path(__file__).resolve().parents[1]
CLUSTER_YAML = ROOT / "cluster.yaml"
VENV = "~/venv/bin/"


@pytest.fixture(scope="module")
def text() -> str:
    return CLUSTER_YAML.read_text()


@pytest.fixture()
def raw(text) -> dict:
    return yaml.safe_load(text)


@pytest.fixture()
def prepared(raw) -> dict:
    """The config as `ray up` sees it after merging defaults (validated by the first test)."""
    return prepare_config(copy.deepcopy(raw))


def commands(cfg: dict, *keys: str) -> list[str]:
    return [c for k in keys for c in cfg.get(k) or []]


ALL_COMMAND_KEYS = (
    "initialization_commands",
    "setup_commands",
    "head_setup_commands",
    "worker_setup_commands",
    "head_start_ray_commands",
    "worker_start_ray_commands",
)


# -- Ray's own validation ----------------------------------------------------------------------
def test_validates_with_rays_validate_config(prepared):
    validate_config(prepared)  # raises on any schema or cross-field error
    assert prepared["provider"]["type"] == "aws"


def _drop_provider_type(cfg):
    del cfg["provider"]["type"]


def _unknown_top_level_key(cfg):
    cfg["worker_instance_type"] = "c6i.4xlarge"


def _string_cpu_count(cfg):
    cfg["available_node_types"]["cpu_worker"]["resources"]["CPU"] = "16"


def _node_type_without_node_config(cfg):
    del cfg["available_node_types"]["cpu_worker"]["node_config"]


@pytest.mark.parametrize(
    "break_it",
    [_drop_provider_type, _unknown_top_level_key, _string_cpu_count, _node_type_without_node_config],
)
def test_malformed_copies_fail_the_same_validation(prepared, break_it):
    bad = copy.deepcopy(prepared)
    break_it(bad)
    with pytest.raises(jsonschema.ValidationError):
        validate_config(bad)


def test_rays_cross_field_checks_run_too(prepared):
    bad = copy.deepcopy(prepared)
    bad["head_node_type"] = "no_such_type"
    with pytest.raises(ValueError, match="head_node_type"):
        validate_config(bad)
    bad = copy.deepcopy(prepared)
    bad["available_node_types"]["cpu_worker"]["min_workers"] = bad["max_workers"] + 1
    with pytest.raises(ValueError, match="max_workers"):
        validate_config(bad)


def test_unknown_key_is_rejected_through_the_whole_ray_up_path(raw):
    raw["setup_comands"] = ["echo typo"]
    with pytest.raises(jsonschema.ValidationError, match="setup_comands"):
        validate_config(prepare_config(raw))


# -- nodes -------------------------------------------------------------------------------------
def test_head_and_cpu_workers(raw):
    types = raw["available_node_types"]
    head = raw["head_node_type"]
    assert head in types
    assert types[head]["resources"] == {"CPU": 0}, "trials belong on the workers"
    workers = {k: v for k, v in types.items() if k != head}
    assert workers
    for name, node in workers.items():
        cpu = node["resources"].get("CPU")
        assert isinstance(cpu, int) and cpu >= 1, name
        assert node["node_config"]["InstanceType"], name
        assert node.get("max_workers", 0) >= (0 if name == "cpu_spot_worker" else 1), name
    assert sum(n.get("min_workers", 0) for n in types.values()) <= raw["max_workers"]
    assert raw["idle_timeout_minutes"] > 0
    for node in types.values():
        assert re.fullmatch(r"ami-[0-9a-f]{8,17}", node["node_config"]["ImageId"])


# -- security ----------------------------------------------------------------------------------
def test_dashboard_bound_to_localhost_only(raw, text):
    head_start = " ".join(raw["head_start_ray_commands"])
    assert "ray start --head" in head_start
    assert "--dashboard-host=127.0.0.1" in head_start
    assert "0.0.0.0" not in text


def test_token_auth_stays_on(raw, prepared, text):
    assert not re.search(r"RAY_AUTH_MODE\W*disabled", text, re.IGNORECASE)
    for key in ("head_start_ray_commands", "worker_start_ray_commands"):
        start = [c for c in raw[key] if "ray start" in c]
        assert start and all("export RAY_AUTH_MODE=token;" in c for c in start), key
    # one token for the whole cluster: the client's, copied to every node
    assert raw["file_mounts"]["~/.ray/auth_token"] == "~/.ray/auth_token"


def test_only_ssh_is_opened_inbound(raw):
    extra = raw["provider"].get("security_group", {}).get("IpPermissions", [])
    for rule in extra:
        assert rule.get("FromPort") == rule.get("ToPort") == 22, rule


# -- software ----------------------------------------------------------------------------------
def test_torch_pinned_to_the_projects_cpu_wheel(prepared):
    pins = [
        d
        for d in tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["dependencies"]
        if d.startswith("torch==")
    ]
    assert pins == ["torch==2.13.0"]
    setup = prepared["setup_commands"]
    torch_cmds = [c for c in setup if "torch" in c]
    assert torch_cmds == [f"{VENV}pip install torch==2.13.0 --index-url https://download.pytorch.org/whl/cpu"]
    ps_ray = f"{VENV}pip install -e ~/ps_ray"
    assert ps_ray in setup
    assert setup.index(torch_cmds[0]) < setup.index(ps_ray), "torch first, or pip picks a CUDA wheel"


def test_setup_installs_ps_ray_from_the_synced_repo(raw, prepared):
    assert raw["file_mounts"]["~/ps_ray"] == "."
    assert ".gitignore" in raw["rsync_filter"] and ".venv" in raw["rsync_exclude"]
    assert ".venv/" in (ROOT / ".gitignore").read_text().split()
    # prepare_config prepends setup_commands to the head's and the workers' own lists
    for key in ("head_setup_commands", "worker_setup_commands"):
        assert f"{VENV}pip install -e ~/ps_ray" in prepared[key], key
    assert any("boto3" in c and c.startswith(VENV) for c in raw["head_setup_commands"]), (
        "the autoscaler runs in the venv on the head and needs boto3 to start workers"
    )


def test_every_ray_command_uses_the_venv(raw):
    for cmd in commands(raw, "head_start_ray_commands", "worker_start_ray_commands"):
        for word in shlex.split(cmd.replace(";", " ; ")):
            if word.endswith("/ray") or word == "ray":
                assert word == f"{VENV}ray", cmd


def test_every_command_is_valid_bash(raw):
    cmds = commands(raw, *ALL_COMMAND_KEYS)
    assert len(cmds) >= 8
    for cmd in cmds:
        res = subprocess.run(["bash", "-n", "-c", cmd], capture_output=True, text=True)
        assert res.returncode == 0, (cmd, res.stderr)


def test_docs_submit_with_an_absolute_entrypoint(raw):
    """`ray job submit` shlex-quotes its entrypoint, so a `~` would never expand on the head."""
    docs = (ROOT / "docs" / "cluster.md").read_text()
    submit = re.search(r"RAY_AUTH_MODE=token \S*ray job submit[^`]*", docs)
    assert submit, "docs/cluster.md shows the job submission"
    assert "--address http://127.0.0.1:8265" in submit.group(0)
    assert f"/home/{raw['auth']['ssh_user']}/venv/bin/ps-ray sweep" in submit.group(0)


def test_a_gpu_worker_type_installs_the_cuda_build_of_the_same_torch(raw, prepared):
    gpu = {k: v for k, v in raw["available_node_types"].items() if v["resources"].get("GPU")}
    assert list(gpu) == ["gpu_worker"] and gpu["gpu_worker"]["resources"]["GPU"] >= 1
    commands = prepared["available_node_types"]["gpu_worker"]["worker_setup_commands"]
    install = [c for c in commands if "pip install torch" in c]
    assert install and all("torch==2.13.0" in c and "whl/cpu" not in c for c in install)
    assert any("torch.cuda.is_available()" in c for c in commands), "a GPU node without CUDA must fail setup"
    # the CPU workers keep the global commands (no GPU type's command leaks into them)
    assert "worker_setup_commands" not in raw["available_node_types"]["cpu_worker"]


def test_a_spot_copy_of_the_cpu_worker_is_there_to_switch_to(raw):
    types = raw["available_node_types"]
    on_demand, spot = types["cpu_worker"], types["cpu_spot_worker"]
    # the same node bought on the spot market, off until switched to
    assert spot["node_config"] == {
        **on_demand["node_config"],
        "InstanceMarketOptions": {"MarketType": "spot"},
    }
    assert spot["resources"] == on_demand["resources"] and spot["max_workers"] == 0
    assert (
        "InstanceMarketOptions" not in on_demand["node_config"]
        and "InstanceMarketOptions" not in (types[raw["head_node_type"]]["node_config"])
    ), "the head runs the driver and the MLflow store: never on spot"
    # switched as the comment says (spot 4, on-demand 0): still a config `ray up` takes
    switched = copy.deepcopy(raw)
    switched["available_node_types"]["cpu_spot_worker"]["max_workers"] = on_demand["max_workers"]
    switched["available_node_types"]["cpu_worker"]["max_workers"] = 0
    validate_config(prepare_config(switched))
    # Ray passes node_config to EC2 unchecked; the spot option is the one of Ray's own AWS defaults
    ray_aws = yaml.safe_load((Path(ray.autoscaler.__file__).parent / "aws" / "defaults.yaml").read_text())
    ray_worker = ray_aws["available_node_types"]["ray.worker.default"]["node_config"]
    assert spot["node_config"]["InstanceMarketOptions"] == ray_worker["InstanceMarketOptions"]
