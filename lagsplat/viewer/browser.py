"""Headless Chromium on a served viewer page (used by the browser test and ``benchmarks/interactive.py``).

Playwright's own browser download does not work on the project's machines;
the system Chromium is launched instead (``apt-get install -y chromium``).
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

__all__ = ["CHROMIUM", "CHROMIUM_ARGS", "CHROMIUM_WEBGL_ARGS", "served_page"]

CHROMIUM = "/usr/bin/chromium"
CHROMIUM_ARGS = ["--no-sandbox", "--disable-gpu", "--disable-background-networking", "--disable-component-update", "--disable-sync", "--no-first-run"]
# WebGL in software (SwiftShader through ANGLE), for viser's 3-D canvas on a machine without a GPU
CHROMIUM_WEBGL_ARGS = ["--no-sandbox", "--use-gl=angle", "--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--disable-background-networking", "--no-first-run"]


@contextmanager
def served_page(session, timeout_ms: int = 30_000, viewport: tuple[int, int] = (1000, 700)) -> Iterator[tuple[object, object, str]]:
    """Serve ``session`` on a free localhost port and open it in headless Chromium.

    Yields ``(page, viewer, url)`` once the page has received three frames;
    the browser and the server are closed on exit.

    Raises:
        ImportError: if Playwright is not installed.
        playwright TimeoutError: if no frame arrives within ``timeout_ms``.
    """
    from playwright.sync_api import sync_playwright

    from lagsplat.viewer.server import Viewer

    viewer = Viewer(session, port=0)
    url = viewer.start()
    try:
        with sync_playwright() as pw:
            browser = pw.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS, headless=True)
            try:
                page = browser.new_page(viewport={"width": viewport[0], "height": viewport[1]})
                page.goto(url)
                page.wait_for_function("window.lagsplatState.framesReceived >= 3", timeout=timeout_ms)
                yield page, viewer, url
            finally:
                browser.close()
    finally:
        viewer.stop()
