#!/usr/bin/env bash
# Set-up and entry points for a fresh machine; each command installs what it needs first.
#   ./run.sh smoke   end-to-end demo on 2 CPUs (render, PS anchors, a short SAC+HER training)
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
    out="${PS_RAY_OUT:-runs/smoke}"
    "$VENV/bin/ps-ray" render --robot panda_l3 --task push --gif "$out/push_random.gif"
    "$VENV/bin/ps-ray" train --robot panda --task reach --method ps --env-steps 6000 \
      --interface-dim 16 --run-dir "$out/train-ps-panda-reach" "$@"
    "$VENV/bin/ps-ray" render --robot panda --task reach --policy "$out/train-ps-panda-reach/policy.safetensors" \
      --gif "$out/reach_trained.gif"
    echo "smoke outputs in $out"
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
