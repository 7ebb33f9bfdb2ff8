"""Open a page (a report file, or the MLflow UI) in headless Chromium: a screenshot, or the text
a person would read once its scripts have run."""

from __future__ import annotations

import html
import re
import shutil
import subprocess
import tempfile
from pathlib import Path

CHROMIUM_NAMES = ("chromium", "chromium-browser", "google-chrome")
# headless on a closed network: no sandbox (root), no GPU, no background or update traffic
FLAGS = (
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--hide-scrollbars",
    "--allow-file-access-from-files",
)


def find_chromium() -> str | None:
    return next((p for p in map(shutil.which, CHROMIUM_NAMES) if p), None)


def _run(page: str | Path, *args: str, width: int, height: int, timeout: float) -> str:
    browser = find_chromium()
    if browser is None:
        raise RuntimeError(
            f"no Chromium found (apt-get install chromium); looked for {', '.join(CHROMIUM_NAMES)}"
        )
    url = page if isinstance(page, str) and "://" in page else Path(page).resolve().as_uri()
    with tempfile.TemporaryDirectory() as profile:
        done = subprocess.run(
            [browser, *FLAGS, f"--user-data-dir={profile}", f"--window-size={width},{height}", *args, url],
            check=True,
            capture_output=True,
            text=True,
            timeout=timeout,
        )
    return done.stdout


def screenshot(
    page: str | Path,
    png: str | Path,
    *,
    width: int = 1280,
    height: int = 4000,
    timeout: float = 120,
    wait_ms: int = 0,
) -> Path:
    """Render ``page`` (an HTML file or a URL) at ``width`` x ``height`` CSS pixels into ``png``;
    ``wait_ms`` of virtual time lets a scripted page (the MLflow UI) fetch and draw its data."""
    png = Path(png).resolve()
    png.parent.mkdir(parents=True, exist_ok=True)
    wait = (f"--virtual-time-budget={wait_ms}",) if wait_ms else ()
    _run(page, *wait, f"--screenshot={png}", width=width, height=height, timeout=timeout)
    if not png.exists():
        raise RuntimeError(f"Chromium wrote no screenshot for {page}")
    return png


def visible_text(page: str | Path, *, wait_ms: int = 20_000, timeout: float = 120) -> str:
    """The text of ``page`` after its scripts ran for ``wait_ms`` of virtual time (tags, scripts
    and styles removed, whitespace collapsed)."""
    wait = (f"--virtual-time-budget={wait_ms}",) if wait_ms else ()
    dom = _run(page, *wait, "--dump-dom", width=1400, height=1000, timeout=timeout)
    dom = re.sub(r"<(script|style)\b.*?</\1>", " ", dom, flags=re.S)
    return " ".join(html.unescape(re.sub(r"<[^>]+>", " ", dom)).split())
