"""Values as MLflow takes them: params flattened to strings (start files relative to the sweep),
metrics as finite floats under the names MLflow allows, batches within its limits."""

from __future__ import annotations

import json
import math
import re
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

MAX_PARAM_CHARS = 6000  # mlflow.utils.validation.MAX_PARAM_VAL_LENGTH


def flatten_params(params: Mapping[str, Any], prefix: str = "") -> dict[str, str]:
    """Nested mappings become ``a.b`` keys; values become strings (lists/None as JSON)."""
    flat: dict[str, str] = {}
    for key, value in params.items():
        name = f"{prefix}{key}"
        if isinstance(value, Mapping):
            flat.update(flatten_params(value, f"{name}."))
        else:
            flat[name] = _param_str(value)
    return flat


PATH_PARAMS = ("init_policy", "anchors")  # files a run starts from: logged relative to its sweep


def relative_paths(params: Mapping[str, str], root: str | Path) -> dict[str, str]:
    """``params`` with each file of :data:`PATH_PARAMS` under the sweep folder ``root`` written
    relative to it, so a run reads the same wherever the sweep folder is moved or mounted."""
    base = Path(root).expanduser().resolve()
    out = dict(params)
    for key in PATH_PARAMS:
        path = Path(out.get(key) or "")
        if path.is_absolute() and path.resolve().is_relative_to(base):
            out[key] = path.resolve().relative_to(base).as_posix()
    return out


def same_param(logged: str, wanted: str) -> bool:
    """Whether a run's logged param is ``wanted``: also a path logged absolute by a run made before
    paths were relative (:func:`relative_paths`), so that run still resumes."""
    return logged == wanted or (logged.startswith("/") and logged.endswith("/" + wanted))


def _param_str(value: Any) -> str:
    text = value if isinstance(value, str) else json.dumps(value, default=str)
    return text[:MAX_PARAM_CHARS]


def finite_float(value: Any) -> float | None:
    """``value`` as a float, or None for None, NaN, infinities and non-numbers."""
    if value is None or isinstance(value, str):
        return None
    try:
        number = float(value)
    except (TypeError, ValueError):
        return None
    return number if math.isfinite(number) else None


def _chunks(items: Sequence[Any], size: int) -> Iterable[Sequence[Any]]:
    for start in range(0, len(items), size):
        yield items[start : start + size]


# MLflow names allow alphanumerics, "_", "-", ".", " ", "/" and ":" only: a translated stitch's
# row "ablation+affine@outcome" is logged as "ablation-affine:outcome", a method with an option,
# "ps_distilled+consolidate_pull=0", as "ps_distilled-consolidate_pull_0"
_METRIC_CHARACTERS = str.maketrans({"+": "-", "@": ":"})
_NOT_IN_METRIC_NAMES = re.compile(r"[^\w.\- /:]")


def metric_name(key: str) -> str:
    """``key`` as an MLflow metric name (any other character becomes "_")."""
    return _NOT_IN_METRIC_NAMES.sub("_", key.translate(_METRIC_CHARACTERS))
