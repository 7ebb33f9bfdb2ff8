#!/usr/bin/env bash
# Set-up and entry points for a fresh machine; each command installs what it needs first.
#   ./run.sh smoke   ps-ray demo (a shipped stitch scored beside its controls), then the whole smoke
#                    pipeline on 2 CPUs (train, zero-shot, few-shot, report; MLflow)
#   ./run.sh test    CI's suite in two lanes: the fast lane, then the end-to-end tests (not the
#                    slow ones); with pytest arguments (-m slow, a file) one run of those instead;
#                    in two pytest-xdist workers, a test file each at a time (-n 0: one process);
#                    it also installs Debian's chromium (headless screenshot of the report)
#   ./run.sh test-fast  the fast lane only: no Ray, no subprocess, no browser, no learning check
#   ./run.sh test-slow  the slow lane, left out of CI to keep it under 15 minutes: learning checks
#                    and cluster services (a killed node, preemption, ray job submit, a tracking
#                    server, the ASHA search killed and resumed); run it before landing a change
#                    to what they check
#   ./run.sh lint    ruff: lint and format check (configured in pyproject.toml)
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

browser() {
  if command -v chromium >/dev/null 2>&1; then return; fi
  if ! command -v apt-get >/dev/null 2>&1; then
    echo "run.sh: no chromium and no apt-get; install Chromium for the report screenshot test" >&2
    return
  fi
  local sudo=""; [ "$(id -u)" = 0 ] || sudo="sudo"
  { $sudo env DEBIAN_FRONTEND=noninteractive apt-get update -q >/dev/null &&
    $sudo env DEBIAN_FRONTEND=noninteractive apt-get install -y -q --no-install-recommends chromium >/dev/null; } ||
    echo "run.sh: installing chromium failed; the report screenshot test will say so" >&2
}

# Two workers keep both cores busy: much of a test is process start-up, I/O and waiting for a
# subprocess, and one file's module-scoped fixtures stay in one worker (--dist loadfile).
pytest() { "$VENV/bin/python" -m pytest -q -n 2 --dist loadfile --no-loadscope-reorder "$@"; }

cmd="${1:-}"
shift || true
case "$cmd" in
  setup) setup ;;
  smoke)
    setup
    out="${PS_RAY_OUT:-runs}"
    "$VENV/bin/ps-ray" demo  # a stitch that works, from the shipped example modules (~20 s)
    "$VENV/bin/ps-ray" render --robot panda_l3 --task push --gif "$out/smoke_render/push_random.gif"
    "$VENV/bin/ps-ray" run sweeps/smoke.yaml --storage "$out/sweeps" "$@"
    ;;
  lint)
    setup
    "$VENV/bin/ruff" check ps_ray tests
    "$VENV/bin/ruff" format --check ps_ray tests
    ;;
  test-fast)
    setup
    pytest -m "not slow and not e2e" "$@"
    ;;
  test)
    setup
    browser
    if [ "$#" -gt 0 ]; then pytest --durations=15 "$@"; exit; fi
    pytest -m "not slow and not e2e"
    pytest -m "e2e and not slow" --durations=15
    ;;
  test-slow)
    setup
    browser
    pytest -m slow --durations=15 "$@"
    ;;
  *)
    echo "usage: ./run.sh smoke|test|test-fast|test-slow|lint|setup [args]" >&2
    exit 2
    ;;
esac
