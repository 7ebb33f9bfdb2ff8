"""The method table's old rows, now keys of the menu (:mod:`ps_ray.specs.methods`): files written
before the menu name them, and their upgrades read them through :func:`upgrade_name`."""

from __future__ import annotations

from typing import Any

# typed in a sweep or on the command line, an old name is refused with the key to write instead
LEGACY: dict[str, str] = {
    "ps_ln": "ps+norm=layer",
    "ps_center": "ps+center=standard",
    "ps_center_ln": "ps+center=standard+norm=layer",
    "ps_mean_ln": "ps+center=mean+norm=layer",
    "ps_nograd": "ps+anchor_grad=false",
    "ps_scaled": "ps+scale=4",
    "ps_normreg": "ps+norm_reg=1",
    "ps_normreg_ln": "ps+norm=layer+norm_reg=1",
    "ps_ref": "ps+norm=layer+norm_reg=1+ref_weight=1",
    "ps_ref_light": "ps+norm=layer+norm_reg=1+ref_weight=0.1",
    "ps_ref_actor": "ps+norm=layer+norm_reg=1+ref_weight=0.1+relative_critics=false",
    "ps_ref_actor_weak": "ps+norm=layer+norm_reg=1+ref_weight=0.03+relative_critics=false",
    "ps_ref_actor_sharp": (
        "ps+norm=layer+norm_reg=1+ref_bandwidth=0.25+ref_weight=0.03+relative_critics=false"
    ),
    "ps_consolidated": (
        "ps+consolidate=true+norm=layer+norm_reg=1+ref_weight=0.03+relative_critics=false+scale=0.25"
    ),
}


def upgrade_names(data: Any) -> Any:
    """A stored spec (a sweep folder's ``sweep.yaml``) in today's words: every string and mapping
    key that is an old row's name (in ``methods``, a stage's ``methods``, ``translate``'s keys)
    becomes its key. The old names are distinct from every other name a spec holds."""
    if isinstance(data, str):
        return upgrade_name(data)
    if isinstance(data, list):
        return [upgrade_names(v) for v in data]
    if isinstance(data, dict):
        return {upgrade_names(k): upgrade_names(v) for k, v in data.items()}
    return data


def upgrade_name(method: str) -> str:
    """A method as a file written before the menu may name it (an old row), as today's key
    names it; only the upgrades of files call it (policy files, training specs)."""
    return LEGACY.get(method, method)
