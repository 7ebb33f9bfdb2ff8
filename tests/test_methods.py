"""The method menu: presets plus options, canonical keys, and policy files that keep their meaning."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import pytest
import torch
from safetensors.torch import load_file

from ps_ray.errors import UserError
from ps_ray.nets.from_signature import signature_of
from ps_ray.nets.policy_file import load_policy, save_policy
from ps_ray.nets.sac import build_sac_nets
from ps_ray.specs.dims import NetDims
from ps_ray.specs.methods import PRESETS, MethodSpec, method_key, method_spec
from ps_ray.specs.old_methods import LEGACY, upgrade_name
from ps_ray.specs.sweep import SweepSpec
from ps_ray.specs.train import SpecError
from ps_ray.stitching.stitch import stitch_policies
from ps_ray.store.signature import read_signature

torch.set_num_threads(1)
OLD = Path(__file__).parent / "data" / "policies_v1"  # written by the code before the menu
OLD_ROWS = sorted(p.name.removesuffix("_0.safetensors") for p in OLD.glob("*_0.safetensors"))


def test_the_menu_is_short_and_every_old_row_is_a_preset_with_options():
    assert len(PRESETS) <= 8
    assert len(OLD_ROWS) == 20 and set(OLD_ROWS) == set(PRESETS) | set(LEGACY)
    for name, key in LEGACY.items():
        preset, *options = method_key(key).split("+")
        assert preset in PRESETS and options, name
        assert upgrade_name(name) == key  # files that name it are read as the key (their upgrades)
        with pytest.raises(UserError) as e:  # typed by a user, it is refused with the key to write
            method_spec(name)
        assert str(e.value) == f"method {name!r} is an old name; write it as {key!r}"


def test_a_key_is_canonical_however_the_options_are_written():
    key = "ps+norm=layer+scale=0.25"
    assert method_key("ps+scale=0.25+norm=layer") == key
    assert method_key({"preset": "ps", "scale": 0.25, "norm": "layer"}) == key
    assert method_key("ps+scale=0.25+norm=layer+center=none") == key  # a preset's own value is not shown
    spec = method_spec(key)
    assert spec.name == key and spec.relative.norm == "layer" and spec.relative.scale == 0.25
    assert (
        method_key("ablation+norm=layer") == "ablation+norm=layer+relative=true"
    )  # a setting switches it on
    assert method_spec("ps+relative=false") == dataclasses.replace(
        PRESETS["ablation"], name="ps+relative=false"
    )


@pytest.mark.parametrize(
    "method, message",
    [
        ("psx", "unknown method 'psx'; valid presets: ps, ps_distilled, ablation, devin, devin_large, plain"),
        ("ps+nrom=layer", "method 'ps+nrom=layer': unknown option 'nrom'; valid: relative, center, norm"),
        ("ps+scale=big", "method option scale: expected a number, got 'big'"),
        ("ps+scale", "method 'ps+scale': option 'scale' is not option=value"),
        ("ps+norm=batch", "method 'ps+norm=batch': unknown relative norm 'batch'"),
        ("plain+relative=true", "method 'plain+relative=true': a relative interface needs a modular network"),
        ("ps+relative=false+norm=layer", "relative=false contradicts norm"),
        ({"norm": "layer"}, "a mapping needs a preset (ps, ps_distilled"),
    ],
)
def test_a_bad_method_is_one_line_naming_it(method, message):
    with pytest.raises(UserError) as info:
        method_spec(method)
    assert message in str(info.value) and "\n" not in str(info.value)


def test_a_sweep_names_variants_by_their_settings_and_refuses_one_twice():
    spec = SweepSpec.from_mapping(
        {
            "name": "v",
            "methods": ["ps", {"preset": "ps", "norm": "layer"}, "ps+ref_weight=0.1+norm_reg=1+norm=layer"],
            "robots": ["panda"],
            "tasks": ["reach"],
            "seeds": [1],
            "zero_shot": {"translate": {"ps+norm=layer": ["affine"]}},
        }
    )
    assert spec.methods == ("ps", "ps+norm=layer", "ps+norm=layer+norm_reg=1+ref_weight=0.1")
    assert [t.method for t in spec.trials()] == list(spec.methods)
    with pytest.raises(SpecError, match="methods: duplicate entries"):
        SweepSpec.from_mapping(
            {
                "name": "v",
                "methods": [{"preset": "ps", "norm": "layer"}, "ps+norm=layer"],
                "robots": ["panda"],
                "tasks": ["reach"],
                "seeds": [1],
            }
        )
    with pytest.raises(SpecError, match="methods: method 'ps\\+norm=batch': unknown relative norm"):
        SweepSpec.from_mapping(
            {"name": "v", "methods": ["ps+norm=batch"], "robots": ["panda"], "tasks": ["reach"], "seeds": [1]}
        )


# Golden outputs were stored on another CPU: float32 kernels there (AVX2 against AVX-512) sum in
# another order, which moves a relative projection's outputs by up to about 2e-5 (1.9e-5 measured);
# the tolerance keeps a margin of five over that
GOLDEN = {"rtol": 1e-3, "atol": 1e-4}


# -- files written before the menu -----------------------------------------------------------------------
@pytest.fixture(scope="module")
def expected() -> dict[str, torch.Tensor]:
    return load_file(str(OLD / "expected.safetensors"))


@pytest.mark.parametrize("row", OLD_ROWS)
def test_an_old_policy_file_loads_stitches_and_acts_as_it_did(row, expected):
    task_in, robot_in, action = expected["task_in"], expected["robot_in"], expected["action"]
    for seed in (0, 1):
        nets, signature = load_policy(OLD / f"{row}_{seed}.safetensors")
        assert signature.method == method_key(upgrade_name(row)) and signature.spec == method_spec(
            signature.method
        )
        with torch.no_grad():
            mean, log_std = nets.eval().actor(task_in, robot_in)
            q = nets.critic(task_in, robot_in, action)
        torch.testing.assert_close(mean, expected[f"{row}_{seed}.mean"], **GOLDEN)
        torch.testing.assert_close(log_std, expected[f"{row}_{seed}.log_std"], **GOLDEN)
        torch.testing.assert_close(q, expected[f"{row}_{seed}.q"], **GOLDEN)
    _assert_stitch_acts_as_it_did(OLD, row, expected)


def _assert_stitch_acts_as_it_did(folder: Path, name: str, expected: dict) -> None:
    """The stitch of golden files ``<name>_0`` (task module) and ``<name>_1`` (robot module)
    computes the stored actor mean and critic value on the stored inputs."""
    task_in, robot_in, action = expected["task_in"], expected["robot_in"], expected["action"]
    stitched, _ = stitch_policies(folder / f"{name}_0.safetensors", folder / f"{name}_1.safetensors")
    with torch.no_grad():
        mean = stitched.eval().actor(task_in, robot_in)[0]
        q = stitched.critic(task_in, robot_in, action)
    torch.testing.assert_close(mean, expected[f"{name}_stitched.mean"], **GOLDEN)
    torch.testing.assert_close(q, expected[f"{name}_stitched.q"], **GOLDEN)


V2 = Path(__file__).parent / "data" / "policies_v2"  # settings stored before hindsight_norm existed


@pytest.mark.parametrize("method", ["ablation", "ps"])
def test_a_file_written_before_a_setting_existed_loads_stitches_and_acts_as_it_did(method):
    """Its stored settings lack the newer setting: read at its default, as its nets are built, so
    that the stitch of two such files is refused by nothing and computes what it did."""
    old = load_file(str(V2 / "expected.safetensors"))
    task_in, robot_in = old["task_in"], old["robot_in"]
    for seed in (0, 1):
        nets, signature = load_policy(V2 / f"{method}_{seed}.safetensors")
        assert signature.spec == method_spec(method) and '"hindsight_norm": true' in signature.settings
        with torch.no_grad():
            mean = nets.eval().actor(task_in, robot_in)[0]
        torch.testing.assert_close(mean, old[f"{method}_{seed}.mean"], **GOLDEN)
    _assert_stitch_acts_as_it_did(V2, method, old)


def test_a_policy_file_keeps_its_settings_whatever_the_menu_becomes(tmp_path, monkeypatch, expected):
    """A file stores the resolved method: redefining the preset it names changes nothing it does."""
    torch.manual_seed(0)
    nets = build_sac_nets(
        "ps", NetDims(6, 8, 7), interface_dim=8, hidden=16, anchors=torch.randn(8, 6).numpy()
    )
    path = save_policy(tmp_path / "p.safetensors", nets, signature_of(nets, "ps", 8, 16))
    task_in, robot_in = expected["task_in"], expected["robot_in"]
    with torch.no_grad():
        before = nets.actor(task_in, robot_in)[0]
    changed = dataclasses.replace(
        PRESETS["ps"], relative=dataclasses.replace(PRESETS["ps"].relative, scale=4.0)
    )
    monkeypatch.setitem(PRESETS, "ps", changed)
    assert method_spec("ps").relative.scale == 4.0  # the menu moved
    loaded, signature = load_policy(path)
    assert isinstance(signature.spec, MethodSpec) and signature.spec.relative.scale == 1.0
    with torch.no_grad():
        torch.testing.assert_close(loaded.actor(task_in, robot_in)[0], before, rtol=1e-5, atol=1e-6)


def test_a_policy_file_whose_settings_disagree_with_its_name_is_refused(tmp_path):
    from safetensors import safe_open
    from safetensors.torch import save_file

    src = OLD / "ps_0.safetensors"
    signature, metadata = read_signature(src)
    with safe_open(str(src), framework="pt") as f:
        state = {k: f.get_tensor(k) for k in f.keys()}
    record = json.loads(metadata["signature"])
    record["settings"] = signature.settings.replace('"scale": 1.0', '"scale": -1.0')
    save_file(
        state, str(tmp_path / "bad.safetensors"), metadata={**metadata, "signature": json.dumps(record)}
    )
    with pytest.raises(UserError, match="bad policy signature: relative scale must be positive, got -1.0"):
        load_policy(tmp_path / "bad.safetensors")


def test_every_format_version_reads_as_the_current_one_and_files_are_written_in_it(tmp_path):
    """Version 1 (settings may be absent, menu names of the time) and version 2 files read as the
    signature version 2 writes; a version this code does not know, or a version-2 file without
    its settings, is refused in one line."""
    from safetensors import safe_open
    from safetensors.torch import save_file

    old = OLD / "ps_ref_light_0.safetensors"
    signature, metadata = read_signature(old)
    assert metadata["format"] == "ps_ray.policy/1" and not json.loads(metadata["signature"]).get("settings")
    assert signature.method == "ps+norm=layer+norm_reg=1+ref_weight=0.1" and signature.settings
    nets, _ = load_policy(old)
    rewritten = save_policy(tmp_path / "now.safetensors", nets, signature)
    again, now = read_signature(rewritten)
    assert now["format"] == "ps_ray.policy/2" and again == signature
    with safe_open(str(old), framework="pt") as f:
        state = {k: f.get_tensor(k) for k in f.keys()}
    for fmt, record, message in [
        (
            "ps_ray.policy/3",
            json.loads(now["signature"]),
            "format 'ps_ray.policy/3'; this code reads ps_ray.policy/1, ps_ray.policy/2",
        ),
        (
            "ps_ray.policy/2",
            json.loads(metadata["signature"]),
            "a ps_ray.policy/2 file must hold its method's settings",
        ),
    ]:
        bad = tmp_path / "bad.safetensors"
        save_file(state, str(bad), metadata={"format": fmt, "signature": json.dumps(record)})
        with pytest.raises(UserError, match=message) as info:
            read_signature(bad)
        assert "\n" not in str(info.value)


def test_a_run_folder_written_before_the_menu_joins_a_zoo_under_its_key(tmp_path):
    """An old sweep's run folder names an old row in its spec.json and its policy file alike."""
    from ps_ray.stitching.zoo import read_entry

    folder = tmp_path / "run"
    folder.mkdir()
    (folder / "policy.safetensors").write_bytes((OLD / "ps_ref_light_0.safetensors").read_bytes())
    spec = {"method": "ps_ref_light", "robot": "panda", "task": "reach", "seed": 1, "interface_dim": 8}
    (folder / "spec.json").write_text(json.dumps(spec))
    entry = read_entry(folder / "policy.safetensors")
    assert entry.key.method == entry.signature.method == "ps+norm=layer+norm_reg=1+ref_weight=0.1"


def test_a_sweep_folder_recorded_before_the_menu_reads_its_old_names_as_keys(tmp_path):
    """A sweep folder's own sweep.yaml is ps_ray's record, so its old names are upgraded; the same
    names typed in a sweep file are refused."""
    from ps_ray.specs.sweep import load_stored_sweep, load_sweep

    data = {
        "name": "old",
        "methods": ["ps_ln", "ablation"],
        "robots": ["panda"],
        "tasks": ["reach"],
        "seeds": [1],
        "zero_shot": {"translate": {"ps_ln": ["affine"]}},
    }
    (tmp_path / "sweep.yaml").write_text(json.dumps(data))  # JSON is YAML
    stored = load_stored_sweep(tmp_path / "sweep.yaml")
    assert stored.methods == ("ps+norm=layer", "ablation")
    assert dict(stored.zero_shot.translate) == {"ps+norm=layer": ["affine"]}
    with pytest.raises(SpecError, match="method 'ps_ln' is an old name; write it as 'ps\\+norm=layer'"):
        load_sweep(tmp_path / "sweep.yaml")
