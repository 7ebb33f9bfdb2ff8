#!/usr/bin/env bash
# Set-up and entry points for a fresh machine; each command installs what it needs first.
#   ./run.sh smoke   the smoke sweep on 2 CPUs (plain sources, k-means anchors, PS/ablation trials, MLflow)
#   ./run.sh test    the test suite (slow learning checks included; add -m "not slow" to skip)
#   ./run.sh setup   only create .venv and install ps_ray
set -euo pipefail
cd "$(dirname "$0")"
VENV="${PS_RAY_VENV:-.venv}"

setup() {
  if [ -x "$VENV/bin/ps-ray" ] && [ "$VENV/.installed" -nt pyproject.toml ]; then return; fi
  python3 -m venv "$VENV"
  "$VENV/bin/pip" install -q --upgrade pip
  # The pinned CPU wheel first: an unpinned torch would pull gigabytes of CUDA packages.
  "$VENV/bin/pip" install -q "torch==2.13.0"
  "$VENV/bin/pip" install -q -e ".[test]"
  touch "$VENV/.installed"
}

cmd="${1:-}"
shift || true
case "$cmd" in
  setup) setup ;;
  smoke)
    setup
    out="${PS_RAY_OUT:-runs}"
    "$VENV/bin/ps-ray" render --robot panda_l3 --task push --gif "$out/smoke_render/push_random.gif"
    "$VENV/bin/ps-ray" sweep sweeps/smoke.yaml --storage "$out/sweeps" "$@"
    echo "MLflow: $VENV/bin/mlflow ui --backend-store-uri sqlite:///$(cd "$out" && pwd)/sweeps/smoke/mlflow.db"
    ;;
  test)
    setup
    "$VENV/bin/python" -m pytest -q "$@"
    ;;
  *)
    echo "usage: ./run.sh smoke|test|setup [args]" >&2
    exit 2
    ;;
esac
