"""What the end-to-end tests start and wait for: `ps-ray` subprocesses with or without the suite's
Ray, servers polled until they answer, pages read in headless Chromium."""

from __future__ import annotations

import html
import os
import re
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

from ps_ray.analysis.browser import run_chromium


def own_ray_env() -> dict[str, str]:
    """This process's environment without RAY_ADDRESS: a subprocess started with it starts its
    own Ray, for tests that kill a run together with every process it started."""
    return {k: v for k, v in os.environ.items() if k != "RAY_ADDRESS"}


def cli_process(*args: str, env: dict | None = None, own_ray: bool = False, **kwargs) -> subprocess.Popen:
    """``ps-ray`` in a subprocess, output in one pipe; it joins the session's Ray (RAY_ADDRESS)
    unless ``own_ray``."""
    return subprocess.Popen(
        [sys.executable, "-m", "ps_ray.cli", *args],
        env={**(own_ray_env() if own_ray else os.environ), **(env or {})},
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        **kwargs,
    )


def page_text(page: str | Path, *, wait_ms: int = 20_000, timeout: float = 120) -> str:
    """The text of ``page`` after its scripts ran for ``wait_ms`` of virtual time (tags, scripts
    and styles removed, whitespace collapsed)."""
    wait = (f"--virtual-time-budget={wait_ms}",) if wait_ms else ()
    dom = run_chromium(page, *wait, "--dump-dom", width=1400, height=1000, timeout=timeout)
    dom = re.sub(r"<(script|style)\b.*?</\1>", " ", dom, flags=re.S)
    return " ".join(html.unescape(re.sub(r"<[^>]+>", " ", dom)).split())


def wait_until_serving(base: str, server: subprocess.Popen, what: str, timeout: float = 300) -> None:
    """Poll ``<base>/health`` until the server answers; fail if it exited or the time ran out."""
    deadline = time.time() + timeout
    while True:
        try:
            with urllib.request.urlopen(f"{base}/health", timeout=2):
                return
        except OSError:
            assert server.poll() is None and time.time() < deadline, f"{what} did not start"
            time.sleep(0.5)
