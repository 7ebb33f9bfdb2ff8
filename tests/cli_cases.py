"""`python -m tests.cli_cases CASES.json RESULTS.json`: `ps-ray` commands run one after another in
this one process, as the bad-input tests give them, so that the interpreter and ps_ray are loaded
once for all of them rather than once a case (about 2.5 s each here).

CASES.json holds a list of ``{"argv": [...], "cwd": DIR, "absent": [PATH, ...]}``. RESULTS.json
gets, per case, its exit code, everything written to the stderr file descriptor while it ran
(Python's and C libraries' alike) and which of its ``absent`` paths exist after it; one JSON line
per case, written as it ends. What a process prints once (at import, a warning's first time, at
exit) shows here in one case at most, so tests/test_bad_input.py also runs one case of each
command in a process of its own and compares."""

from __future__ import annotations

import json
import os
import sys
import tempfile
import traceback
import warnings
from pathlib import Path

from ps_ray.cli.commands import main


def run_case(argv: list[str], cwd: str) -> tuple[int, str]:
    """``ps-ray *argv`` in ``cwd``: its exit code and its stderr."""
    os.chdir(cwd)
    # a changed filter forgets which warnings were shown: each case sees its own first time
    warnings.simplefilter("default")
    with tempfile.TemporaryFile(mode="w+") as err:
        sys.stderr.flush()
        saved = os.dup(2)
        os.dup2(err.fileno(), 2)
        try:
            code = main(argv)
        except SystemExit as e:  # argparse and explicit exits, as the interpreter ends on them
            code = 0 if e.code is None else e.code if isinstance(e.code, int) else 1
            if not isinstance(e.code, int | None):
                print(e.code, file=sys.stderr)
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
    with open(results_file, "w") as out:
        for case in json.loads(Path(cases_file).read_text()):
            code, stderr = run_case(case["argv"], case["cwd"])
            present = [p for p in case["absent"] if os.path.exists(p)]
            out.write(json.dumps({"code": code, "stderr": stderr, "present": present}) + "\n")
            out.flush()  # a case that hangs or crashes the process leaves the others' results


if __name__ == "__main__":
    run_cases(*sys.argv[1:3])
