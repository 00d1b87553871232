"""Debian's headless Chromium as the HMI's browser tests and benchmark drive it (Selenium).

The binaries are Debian's chromium and chromium-driver (`make tools` installs them; no browser
download). Selenium is imported when options are made, so importing this module costs nothing.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

CHROMIUM = Path("/usr/bin/chromium")
CHROMEDRIVER = Path("/usr/bin/chromedriver")


def chrome_options(width: int, height: int) -> Any:
    """Selenium ChromeOptions for Debian's Chromium, headless, in a ``width`` x ``height`` window
    (sandbox, GPU, shared memory, extensions and the first-run page off, as a container needs)."""
    from selenium import webdriver  # noqa: PLC0415  (a dev dependency: only browser tests and the bench use it)

    opts = webdriver.ChromeOptions()
    opts.binary_location = str(CHROMIUM)
    for arg in (
        "--headless=new",
        "--no-sandbox",
        "--disable-gpu",
        "--disable-dev-shm-usage",
        "--disable-extensions",
        "--no-first-run",
        f"--window-size={width},{height}",
    ):
        opts.add_argument(arg)
    return opts
