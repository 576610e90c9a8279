"""The HTML report in a real headless Chromium (Debian's package; `make browser-deps` installs
it and CI runs that first): the page loads without console errors, every image decodes, a
click opens the viewer at 100 %, and a screenshot is not blank.

Locally the test is skipped, with the reason, when no Chromium is installed; under CI
(CI=true) a missing browser is a failure."""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess

import numpy as np
import pytest

from facetex.cli import main

BROWSERS = ("chromium", "chromium-browser", "google-chrome")
FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
         "--disable-component-update", "--disable-sync", "--no-first-run", "--disable-default-apps",
         "--hide-scrollbars"]


def _browser() -> str:
    for name in BROWSERS:
        path = shutil.which(name)
        if path:
            return path
    if os.environ.get("CI"):
        pytest.fail("Chromium is not installed: CI must run `make browser-deps` before the tests")
    pytest.skip("Chromium is not installed (sudo apt-get install chromium, or `make browser-deps`): "
                "the report's browser test is skipped")


def _chromium(browser, tmp_path, *args, url):
    profile = tmp_path / f"profile{len(list(tmp_path.glob('profile*')))}"
    cmd = [browser, *FLAGS, f"--user-data-dir={profile}", "--enable-logging=stderr", "--v=0",
           "--virtual-time-budget=8000", *args, url]
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=180)
    return r


def _console_lines(stderr: str, page: str) -> list[str]:
    return [line for line in stderr.splitlines() if "CONSOLE" in line and page in line]


@pytest.fixture(scope="module")
def report(runs, frl, tmp_path_factory):
    out = tmp_path_factory.mktemp("report") / "report.html"
    assert main(["report", str(runs[0]), str(runs[1]), "-o", str(out), "--data", str(frl)]) == 0
    return out


def test_report_loads_decodes_and_zooms_in_chromium(report, tmp_path):
    browser = _browser()
    url = report.resolve().as_uri()
    r = _chromium(browser, tmp_path, "--dump-dom", url=url + "#selftest")
    assert r.returncode == 0, r.stderr[-2000:]
    m = re.search(r'<pre id="selftest-result"[^>]*>(.*?)</pre>', r.stdout, re.S)
    assert m and m.group(1).strip(), "the page's self-test did not run (a script error?)"
    res = json.loads(m.group(1))
    assert res["errors"] == []
    assert res["images"] >= 30 and res["decoded"] == res["images"]  # every embedded image decoded
    v = res["viewer"]
    assert v["open"] and v["buttons"] == 5 and v["same_source"]
    assert v["shown"] == v["natural"] and v["natural"][0] > 180  # at 100 %, larger than its thumbnail
    assert _console_lines(r.stderr, report.name) == []  # no console message at all from the page


def test_console_errors_would_be_seen(tmp_path):
    """The check above can fail: a page with a script error shows it in both places."""
    browser = _browser()
    bad = tmp_path / "bad.html"
    bad.write_text("<html><body><script>console.error('boom'); undefinedFunction();</script></body></html>")
    r = _chromium(browser, tmp_path, "--dump-dom", url=bad.as_uri())
    lines = _console_lines(r.stderr, "bad.html")
    assert any("boom" in line for line in lines) and any("undefinedFunction" in line for line in lines)


def test_report_screenshot_is_not_blank(report, tmp_path):
    from facetex.io import read_image

    browser = _browser()
    shots = {}
    for name, frag in (("overview", ""), ("zoom", "#selftest-zoom")):
        png = tmp_path / f"{name}.png"
        r = _chromium(browser, tmp_path, "--window-size=1280,1600", f"--screenshot={png}",
                      url=report.resolve().as_uri() + frag)
        assert r.returncode == 0 and png.is_file(), r.stderr[-2000:]
        img = read_image(png)
        shots[name] = img
        assert img.shape[:2] == (1600, 1280)
        assert img.std() > 0.05  # not one flat colour
        assert len(np.unique((img[::4, ::4] * 255).astype(np.uint8).reshape(-1, 3), axis=0)) > 200
    # the viewer shows a face at 100 % on a dark background: the two screenshots differ
    assert np.abs(shots["overview"] - shots["zoom"]).mean() > 0.1
    keep = os.environ.get("FACETEX_REPORT_SCREENSHOT")
    if keep:  # for a person to look at
        shutil.copy(tmp_path / "overview.png", keep)
