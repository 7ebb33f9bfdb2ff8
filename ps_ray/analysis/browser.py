"""Open a report in headless Chromium and save a screenshot (what a person would see)."""

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


def screenshot(
    page: str | Path, png: str | Path, *, width: int = 1280, height: int = 4000, timeout: float = 120
) -> Path:
    """Render ``page`` (an HTML file) at ``width`` x ``height`` CSS pixels into ``png``."""
    browser = find_chromium()
    if browser is None:
        raise RuntimeError(
            f"no Chromium found (apt-get install chromium); looked for {', '.join(CHROMIUM_NAMES)}"
        )
    png = Path(png).resolve()
    png.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory() as profile:
        subprocess.run(
            [
                browser,
                *FLAGS,
                f"--user-data-dir={profile}",
                f"--window-size={width},{height}",
                f"--screenshot={png}",
                Path(page).resolve().as_uri(),
            ],
            check=True,
            capture_output=True,
            timeout=timeout,
        )
    if not png.exists():
        raise RuntimeError(f"Chromium wrote no screenshot for {page}")
    return png
