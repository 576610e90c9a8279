"""The HTML report in a real headless Chromium, driven by Playwright (Debian's Chromium through
``executable_path``; `make browser-deps` installs it and CI runs that first): no console
errors, every image decodes, a click on a column header sorts the per-pair table, a click on
a row opens the viewer with native-resolution zooms, the table of contents' anchors work, and
the first screen is not blank (``FACETEX_REPORT_SCREENSHOT=path.png`` keeps it to look at).

Locally the tests are skipped, with the reason, when Playwright or Chromium is missing; under
CI (CI=true) that is a failure."""

from __future__ import annotations

import os
import shutil

import numpy as np
import pytest

from facetex.cli import main


@pytest.fixture(scope="module")
def browser():
    from _chromium import chromium_path

    path = chromium_path("report")
    from playwright.sync_api import sync_playwright

    with sync_playwright() as p:
        b = p.chromium.launch(executable_path=path, args=["--no-sandbox", "--disable-gpu"])
        yield b
        b.close()


@pytest.fixture(scope="module")
def report(runs, frl, tmp_path_factory):
    out = tmp_path_factory.mktemp("report") / "report.html"
    assert main(["report", str(runs[0]), str(runs[1]), "-o", str(out), "--data", str(frl), "-q"]) == 0
    return out


@pytest.fixture()
def page(browser, report):
    pg = browser.new_page(viewport={"width": 1280, "height": 800})
    messages = []
    pg.on("console", lambda m: messages.append(f"{m.type}: {m.text}"))
    pg.on("pageerror", lambda e: messages.append(f"pageerror: {e}"))
    pg.goto(report.resolve().as_uri())
    pg.wait_for_load_state("load")
    pg.messages = messages
    yield pg
    pg.close()


def test_loads_without_console_errors_and_every_image_decodes(page):
    assert page.messages == []
    n, bad = page.evaluate("""() => { const imgs = Array.from(document.images);
        return [imgs.length, imgs.filter(i => !(i.complete && i.naturalWidth > 0)).map(i => i.alt)]; }""")
    assert n >= 2 * 3 * 5 + 2 * 3 * 6 * 4 and bad == []  # thumbnails and zoom crops of both runs


def test_console_errors_would_be_seen(browser, tmp_path):
    """The check above can fail: a page with a script error reports it."""
    bad = tmp_path / "bad.html"
    bad.write_text("<html><body><script>console.error('boom'); undefinedFunction();</script></body></html>")
    pg = browser.new_page()
    messages = []
    pg.on("console", lambda m: messages.append(m.text))
    pg.on("pageerror", lambda e: messages.append(str(e)))
    pg.goto(bad.as_uri())
    pg.wait_for_load_state("load")
    assert any("boom" in m for m in messages) and any("undefinedFunction" in m for m in messages)


def _column(page, table, header_title):
    return page.evaluate("""([table, title]) => {
        const t = document.querySelector(table), ths = Array.from(t.tHead.rows[0].cells);
        const col = ths.findIndex(th => th.title === title);
        return Array.from(t.tBodies[0].rows).map(r => parseFloat(r.cells[col].dataset.v)); }""", [table, header_title])


def test_clicking_a_header_sorts_the_pair_table(page):
    table = "table.items[data-group='r1']"
    titles = page.eval_on_selector_all(f"{table} th[data-sort=num][title]", "ths => ths.map(t => t.title)")
    # a metric column not already in ascending order (else sorting it would show nothing)
    title = next(t for t in titles if _column(page, table, t) != sorted(_column(page, table, t)))
    before = _column(page, table, title)
    assert len(before) == 3
    page.click(f"{table} th[title='{title}']")
    assert _column(page, table, title) == sorted(before)
    assert page.get_attribute(f"{table} th[title='{title}']", "aria-sort") == "ascending"
    page.click(f"{table} th[title='{title}']")
    assert _column(page, table, title) == sorted(before, reverse=True)
    page.click(f"{table} th:first-child")  # back to the bench's order
    assert page.evaluate(f"Array.from(document.querySelector(\"{table}\").tBodies[0].rows).map(r => r.dataset.open)") \
        == ["r1-0", "r1-1", "r1-2"]


def test_clicking_a_row_opens_the_viewer_with_native_zooms(page):
    assert not page.is_visible("#viewer")
    page.click("table.items[data-group='r1'] tbody tr:nth-child(2) td.lab")
    assert page.is_visible("#viewer") and page.is_visible("#r1-1")
    assert page.inner_text("#viewer-caption") == page.get_attribute("#r1-1", "data-label")
    crops = page.evaluate("""() => Array.from(document.querySelectorAll('#r1-1 img.crop')).map(i => {
        const r = i.getBoundingClientRect();
        return [i.naturalWidth, i.naturalHeight, r.width, r.height, +i.dataset.scale]; })""")
    assert len(crops) == 6 * 4
    for nw, nh, w, h, k in crops:  # native pixels, enlarged by a whole factor to >= 200 px
        assert nw > 0 and (w, h) == (nw * k, nh * k) and min(w, h) >= 200
    thumbs = page.evaluate("Array.from(document.querySelectorAll('#r1-1 .vthumbs img')).map(i => i.naturalWidth)")
    assert len(thumbs) == 5 and min(thumbs) > 64
    page.keyboard.press("ArrowRight")
    assert page.is_visible("#r1-2") and not page.is_visible("#r1-1")
    page.keyboard.press("Escape")
    assert not page.is_visible("#viewer")


def test_table_of_contents_anchors_work(page):
    links = page.eval_on_selector_all("#toc a", "as => as.map(a => a.getAttribute('href'))")
    assert len(links) >= 12
    for href in links:
        assert page.locator(href).count() == 1, href
    page.click("#toc a[href='#r2-pairs']")
    top = page.evaluate("document.getElementById('r2-pairs').getBoundingClientRect().top")
    assert abs(top) < 5  # scrolled to the heading


def test_first_screen_is_not_blank(page, tmp_path):
    from facetex.io import read_image

    png = tmp_path / "first.png"
    page.screenshot(path=str(png))
    img = read_image(png)
    assert img.shape[:2] == (800, 1280) and img.std() > 0.05
    assert page.evaluate("document.getElementById('r1-table1').getBoundingClientRect().top") < 800  # Table 1 on screen
    keep = os.environ.get("FACETEX_REPORT_SCREENSHOT")
    if keep:  # for a person to look at
        shutil.copy(png, keep)
    assert len(np.unique((img[::4, ::4] * 255).astype(np.uint8).reshape(-1, 3), axis=0)) > 50
