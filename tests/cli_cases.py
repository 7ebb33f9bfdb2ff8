"""`python -m tests.cli_cases CASES.json RESULTS.json`: `ps-ray` commands run one after another in
this one process, as the bad-input tests give them, so that the interpreter and ps_ray are loaded
once for all of them rather than once a case (about 2.5 s each here).

CASES.json holds a list of ``{"argv": [...], "cwd": DIR, "absent": [PATH, ...]}``. RESULTS.json
gets, per case, its exit code, everything written to the stderr file descriptor while it ran
(Python's and C libraries' alike, as a subprocess of its own would show it) and which of its
``absent`` paths exist after it."""

from __future__ import annotations

import json
import os
import sys
import tempfile
import traceback
from pathlib import Path

from ps_ray.cli.commands import main


def run_case(argv: list[str], cwd: str) -> tuple[int, str]:
    """``ps-ray *argv`` in ``cwd``: its exit code and its stderr."""
    os.chdir(cwd)
    with tempfile.TemporaryFile(mode="w+") as err:
        sys.stderr.flush()
        saved = os.dup(2)
        os.dup2(err.fileno(), 2)
        try:
            code = main(argv)
        except SystemExit as e:  # argparse and explicit exits
            code = e.code if isinstance(e.code, int) else 1
        except BaseException:  # a bug: its traceback, as the interpreter would print it
            traceback.print_exc()
            code = 1
        finally:
            sys.stderr.flush()
            os.dup2(saved, 2)
            os.close(saved)
        err.seek(0)
        return code, err.read()


def run_cases(cases_file: str, results_file: str) -> None:
    results = []
    for case in json.loads(Path(cases_file).read_text()):
        code, stderr = run_case(case["argv"], case["cwd"])
        present = [p for p in case["absent"] if os.path.exists(p)]
        results.append({"code": code, "stderr": stderr, "present": present})
    Path(results_file).write_text(json.dumps(results))


if __name__ == "__main__":
    run_cases(*sys.argv[1:3])
