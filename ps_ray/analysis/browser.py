"""Open a page (a report file, or the MLflow UI) in headless Chromium and take a screenshot."""

from __future__ import annotations

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


def run_chromium(page: str | Path, *args: str, width: int, height: int, timeout: float) -> str:
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
    run_chromium(page, *wait, f"--screenshot={png}", width=width, height=height, timeout=timeout)
    if not png.exists():
        raise RuntimeError(f"Chromium wrote no screenshot for {page}")
    return png
