"""End to end: the real `ngpmc serve` server (uvicorn, a free port on 127.0.0.1) driven by
headless Chromium through Playwright: draw a stroke, click Grow, see a vine; upload a picture;
an empty canvas. Needs the system Chromium (Debian: `apt-get install chromium`; never a
browser download) and the `playwright` package; skipped with the reason when either is
missing."""

from __future__ import annotations

import os
import shutil
import tempfile
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

WEB_EXTRA = 'ngpmc serve needs the [web] extra: pip install -e ".[web]"'
pytest.importorskip("starlette", reason=WEB_EXTRA)
pytest.importorskip("uvicorn", reason=WEB_EXTRA)
sync_api = pytest.importorskip(
    "playwright.sync_api", reason="the browser test needs Playwright: pip install playwright"
)


def find_chromium() -> str | None:
    for cand in (
        os.environ.get("NGPM_CHROMIUM"),
        "/usr/bin/chromium",
        shutil.which("chromium"),
        shutil.which("chromium-browser"),
    ):
        if cand and Path(cand).is_file() and os.access(cand, os.X_OK):
            return cand
    return None


CHROMIUM = find_chromium()
if CHROMIUM is None:
    pytest.skip(
        "no Chromium browser installed (Debian: apt-get install chromium; or set NGPM_CHROMIUM)",
        allow_module_level=True,
    )

from PIL import Image, ImageDraw  # noqa: E402

from ngpm_compiler.web.app import bind, make_server  # noqa: E402
from ngpm_compiler.web.config import load_config  # noqa: E402

# The network is closed: these flags keep Chromium from waiting on it.
CHROMIUM_ARGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
]


@pytest.fixture(scope="module")
def server_url() -> Iterator[str]:
    sock = bind(0)
    server = make_server(load_config(), sock)
    thread = threading.Thread(target=server.run, kwargs={"sockets": [sock]}, daemon=True)
    thread.start()
    deadline = time.monotonic() + 30
    while not server.started:
        assert thread.is_alive() and time.monotonic() < deadline, "the server did not start"
        time.sleep(0.05)
    yield f"http://127.0.0.1:{sock.getsockname()[1]}/"
    server.should_exit = True
    thread.join(10)
    sock.close()


@pytest.fixture(scope="module")
def browser() -> Iterator[Any]:
    with sync_api.sync_playwright() as pw, tempfile.TemporaryDirectory() as profile:
        ctx = pw.chromium.launch_persistent_context(
            profile,
            executable_path=CHROMIUM,
            headless=True,
            args=CHROMIUM_ARGS,
            viewport={"width": 1240, "height": 860},
        )
        try:
            yield ctx
        finally:
            ctx.close()


@pytest.fixture()
def page(browser: Any, server_url: str) -> Iterator[Any]:
    page = browser.new_page()
    errors: list[str] = []
    page.on("pageerror", lambda err: errors.append(str(err)))
    page.goto(server_url)
    page.wait_for_selector("body[data-ready='1']", timeout=20000)
    yield page
    page.close()
    assert not errors, errors


def draw_stroke(page: Any, points: list[tuple[float, float]]) -> None:
    """A mouse stroke through points given as fractions of the drawing area."""
    box = page.locator("#stage").bounding_box()

    def at(p: tuple[float, float]) -> tuple[float, float]:
        return box["x"] + p[0] * box["width"], box["y"] + p[1] * box["height"]

    page.mouse.move(*at(points[0]))
    page.mouse.down()
    for p in points[1:]:
        page.mouse.move(*at(p), steps=10)
    page.mouse.up()


def painted_pixels(page: Any, canvas: str) -> int:
    return page.evaluate(
        """(id) => {
        const c = document.getElementById(id);
        const d = c.getContext('2d').getImageData(0, 0, c.width, c.height).data;
        let n = 0;
        for (let i = 3; i < d.length; i += 4) if (d[i] > 0) n++;
        return n;
    }""",
        canvas,
    )


def test_draw_a_stroke_grow_and_see_the_vine(page: Any) -> None:
    assert page.is_visible("#hint")
    draw_stroke(page, [(0.5, 0.88), (0.5, 0.55), (0.3, 0.25), (0.25, 0.15)])
    draw_stroke(page, [(0.5, 0.55), (0.72, 0.22)])
    assert page.is_hidden("#hint") and painted_pixels(page, "ink") > 1000
    assert painted_pixels(page, "vine") == 0
    # place the start: click at the foot of the stroke, drag upward
    page.click("[data-tool='start']")
    draw_stroke(page, [(0.5, 0.86), (0.5, 0.7)])
    assert not page.is_checked("#auto-start") and painted_pixels(page, "marks") > 0
    assert "placed at (0.50, 0.86), heading 90°" in page.inner_text("#start-note")
    page.click("[data-tool='brush']")
    page.click("#grow")
    page.wait_for_selector("#result[data-state='done']", timeout=60000)
    assert painted_pixels(page, "vine") > 500  # the vine is drawn over the shape
    assert page.locator("#stage").get_attribute("class").split().count("grown") == 1
    sim = float(page.inner_text("#similarity"))
    assert -1.0 <= sim <= 1.0
    assert float(page.inner_text("#seconds")) > 0
    assert page.get_attribute("#dl-png", "href").startswith("data:image/png;base64,")
    assert page.get_attribute("#dl-svg", "href").startswith("data:image/svg+xml;base64,")
    assert page.get_attribute("#model-view", "src").startswith("data:image/png")
    assert "Done" in page.inner_text("#status") and page.is_hidden("#error")
    # drawing again clears the vine
    draw_stroke(page, [(0.1, 0.9), (0.2, 0.9)])
    assert painted_pixels(page, "vine") == 0


def test_upload_a_picture_then_grow_unguided(page: Any, tmp_path: Path) -> None:
    img = Image.new("RGB", (300, 200), "white")
    ImageDraw.Draw(img).ellipse((100, 30, 200, 170), fill=(30, 30, 30))
    path = tmp_path / "blob.jpg"
    img.save(path)
    page.set_input_files("#file", str(path))
    page.wait_for_function("document.getElementById('hint').hidden === true", timeout=20000)
    assert painted_pixels(page, "ink") > 1000
    page.click("#mode-prior")
    page.fill("#particles", "5")
    page.dispatch_event("#particles", "change")
    page.click("#grow")
    page.wait_for_selector("#result[data-state='done']", timeout=60000)
    assert "unguided" in page.inner_text("#status")
    assert painted_pixels(page, "vine") > 0


def test_an_example_with_its_start_and_an_empty_canvas(page: Any) -> None:
    page.click("#grow")
    assert "Draw a shape first" in page.inner_text("#error")
    page.click("button[data-example='heart']")
    page.wait_for_function("document.getElementById('hint').hidden === true", timeout=20000)
    assert not page.is_checked("#auto-start")  # the example's own start is placed
    assert painted_pixels(page, "marks") > 0  # its arrow
    page.click("#grow")
    page.wait_for_selector("#result[data-state='done']", timeout=60000)
    assert float(page.inner_text("#similarity")) > 0.2
