"""The benchmark report in a real headless browser: every image loads, no nan/undefined shows.

Needs Playwright (in the test extra) and a Chromium: Playwright's own download, or the system's
(Debian/Ubuntu: ``apt-get install chromium``; set ``$CHROMIUM`` to another executable). Skips with
the reason when neither is there. The screenshot is saved next to the report (``report.png``).
"""

from __future__ import annotations

import os
import re
import shutil
from pathlib import Path

import pytest

from shape_toolkit.bench.config import parse_config
from shape_toolkit.bench.report import write_report
from shape_toolkit.bench.runner import run_benchmark

CONFIG = {
    "run": {"name": "browser-check", "random_state": 0},
    "datasets": [{"name": "articulated", "kind": "synthetic",
                  "params": {"n_poses": 2, "subdivisions": 2, "random_state": 0}}],
    "corruptions": [{"name": "noise", "kind": "gaussian-noise", "params": {"strength": [0.2]}}],
    "tasks": [
        {"task": "segmentation", "corruptions": ["none", "noise"], "metrics": ["n_segments", "segmentation"],
         "methods": [{"plugin": "eigvec-gmm", "params": {"n_segments": 6}},
                     {"plugin": "spectral-clustering", "params": {"n_segments": 6}}]},
        {"task": "matching", "metrics": ["geodesic_error", "coverage"],
         "options": {"geodesic_method": "dijkstra", "truth_sample": 100},
         "methods": [{"pipeline": "zoomout-fast"}, {"plugin": "eigvec-alignment"}]},
    ],
}


def _chromium() -> str | None:
    for c in (os.environ.get("CHROMIUM"), "chromium", "chromium-browser", "google-chrome"):
        if c and (shutil.which(c) or Path(c).is_file()):
            return shutil.which(c) or c
    return None


@pytest.fixture(scope="module")
def report(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("run")
    cfg = parse_config(CONFIG, base=out)
    s = run_benchmark(cfg, out / "run", progress=False)
    assert s.failed == 0
    return write_report(out / "run")["html"]


def test_report_in_headless_browser(report):
    sync_api = pytest.importorskip("playwright.sync_api", reason="playwright is not installed (pip install '.[test]')")
    exe = _chromium()
    with sync_api.sync_playwright() as pw:
        try:
            browser = pw.chromium.launch(executable_path=exe, args=["--no-sandbox"]) if exe else pw.chromium.launch()
        except Exception as exc:  # no browser binary at all
            pytest.skip(f"no Chromium to drive (apt-get install chromium, or set $CHROMIUM): {str(exc)[:120]}")
        try:
            page = browser.new_page(viewport={"width": 1280, "height": 900})
            page.goto(report.resolve().as_uri())
            page.wait_for_load_state("load")
            widths = page.eval_on_selector_all("img", "els => els.map(e => e.complete ? e.naturalWidth : 0)")
            assert widths and all(w > 0 for w in widths), widths
            shown = page.inner_text("body")
            bad = re.findall(r".{0,30}\b(?:nan|NaN|undefined|None)\b.{0,10}", shown)
            assert not bad, bad
            # full-width figures: rendered wider than the old 620 px cap
            assert max(page.eval_on_selector_all("img", "els => els.map(e => e.clientWidth)")) > 900
            assert page.locator("details").count() >= 2 and page.locator("td.best").count() >= 1
            page.screenshot(path=str(report.parent / "report.png"), full_page=True)
        finally:
            browser.close()
    assert (report.parent / "report.png").stat().st_size > 10_000
