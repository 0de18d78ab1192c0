"""Checking that a report renders: a screenshot in headless Chromium (`screenshot`) and how
much of it is drawn (`screenshot_coverage`)."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import numpy as np

from .kit import existing_file

CHROMIUM_NAMES = ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable")


def find_chromium() -> str | None:
    """Path of a Chromium/Chrome executable on PATH, or None."""
    return next((p for p in map(shutil.which, CHROMIUM_NAMES) if p), None)


def screenshot(html_path, png_path, width: int = 1200, height: int = 4000,
               chromium: str | None = None, timeout: float = 120) -> Path:
    """Render `html_path` in headless Chromium and save a PNG of the top `height` px.
    ValueError when no Chromium is found; RuntimeError when it fails."""
    chromium = chromium or find_chromium()
    if chromium is None:
        raise ValueError(f"no Chromium found on PATH (tried {CHROMIUM_NAMES})")
    html_path, png_path = Path(html_path).resolve(), Path(png_path).resolve()
    existing_file(html_path, "report")
    png_path.parent.mkdir(parents=True, exist_ok=True)
    png_path.unlink(missing_ok=True)
    cmd = [chromium, "--headless", "--no-sandbox", "--disable-gpu", "--hide-scrollbars",
           f"--window-size={width},{height}", f"--screenshot={png_path}", html_path.as_uri()]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)
    if proc.returncode != 0 or not png_path.is_file():
        raise RuntimeError(f"{chromium} failed ({proc.returncode}): {proc.stderr[-2000:]}")
    return png_path


def screenshot_coverage(png_path) -> dict:
    """How much of a screenshot is drawn: fraction of non-white pixels overall, and of rows
    holding any non-white pixel (a blank or unstyled page scores near 0)."""
    from PIL import Image

    with Image.open(png_path) as image:
        grey = np.asarray(image.convert("L"), dtype=np.uint8)
    ink = grey < 245
    return {"height": int(grey.shape[0]), "width": int(grey.shape[1]),
            "ink_fraction": float(ink.mean()), "rows_with_ink": float(ink.any(axis=1).mean())}
