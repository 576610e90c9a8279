"""Debian's Chromium for the browser tests (report, studio): its path, or a skip that says what to
install (a failure on CI, which must have it: `make browser-deps`)."""

from __future__ import annotations

import os
import shutil

import pytest

BROWSERS = ("chromium", "chromium-browser", "google-chrome")


def missing(reason: str, what: str):
    """Skip (fail on CI) ``what``'s browser tests for ``reason``."""
    if os.environ.get("CI"):
        pytest.fail(f"{reason}: CI must install the test extra and run `make browser-deps` before the tests")
    pytest.skip(f"{reason} (pip install -e '.[test]'; sudo apt-get install chromium, or `make browser-deps`): "
                f"the {what}'s browser tests are skipped")


def chromium_path(what: str) -> str:
    """The Chromium executable, after checking Playwright imports; else :func:`missing`."""
    try:
        import playwright.sync_api  # noqa: F401
    except ImportError:
        missing("Playwright is not installed", what)
    path = next((shutil.which(n) for n in BROWSERS if shutil.which(n)), None)
    if path is None:
        missing("Chromium is not installed", what)
    return path
