"""Headless Chromium for the browser tests (the viewer, the exported web page): Debian's chromium,
installed by scripts/setup_browser.sh, driven by Playwright through its executable path."""

from __future__ import annotations

import os
import shutil
from collections.abc import Iterator

from shared_data import require_installed, require_module

CHROMIUM = os.environ.get("LIQUIDGS_CHROMIUM") or shutil.which("chromium") or "/usr/bin/chromium"
# Without the background-networking flags, connections are refused on a closed network.
QUIET_FLAGS = ["--headless", "--no-sandbox", "--no-first-run", "--disable-background-networking",
               "--disable-component-update"]  # fmt: skip


def launched_chromium(flags: list[str]) -> Iterator:
    """A Playwright browser on CHROMIUM with QUIET_FLAGS and `flags`, for a fixture to yield from;
    skips (fails under CI) without Playwright or Chromium."""
    sync_api = require_module("playwright.sync_api")
    missing = f"no Chromium at {CHROMIUM}: scripts/setup_browser.sh installs Debian's chromium (needs root)"
    require_installed(CHROMIUM, missing)
    with sync_api.sync_playwright() as playwright:
        browser = playwright.chromium.launch(executable_path=CHROMIUM, args=[*QUIET_FLAGS, *flags])
        yield browser
        browser.close()
