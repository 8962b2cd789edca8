"""The web viewer in headless Chromium (Debian's ``chromium``, driven by Playwright): the
stream shows changing, non-black frames, a drag orbits the camera and changes the view, the
stats fill in, the denoise toggle makes the session denoise its stream, and a still renders
and downloads.

Needs the ``chromium`` package: the fixture installs it with apt-get when it is missing and
this runs as root (set TILERENDER_NO_BROWSER_INSTALL=1 to skip instead)."""

import io
import os
import shutil
import subprocess
import time

import httpx
import numpy as np
import pytest
from PIL import Image

from tests.api.conftest import tiny_json

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def chromium() -> str:
    path = shutil.which("chromium") or shutil.which("chromium-browser")
    if (
        path is None
        and os.geteuid() == 0
        and shutil.which("apt-get")
        and not os.environ.get("TILERENDER_NO_BROWSER_INSTALL")
    ):
        env = {**os.environ, "DEBIAN_FRONTEND": "noninteractive"}
        subprocess.run(["apt-get", "update", "-qq"], env=env, timeout=600, check=False)
        subprocess.run(
            ["apt-get", "install", "-y", "-qq", "chromium"], env=env, timeout=900, check=False
        )
        path = shutil.which("chromium")
    if path is None:
        pytest.skip("Debian's chromium is not installed")
    return path


@pytest.fixture
def browser(chromium):
    playwright = pytest.importorskip("playwright.sync_api")
    with playwright.sync_playwright() as p:
        browser = p.chromium.launch(
            executable_path=chromium, headless=True, args=["--no-sandbox", "--disable-gpu"]
        )
        yield browser
        browser.close()


def shot(page) -> np.ndarray:
    data = page.locator("#stream").screenshot()
    return np.asarray(Image.open(io.BytesIO(data)).convert("RGB"), np.float64)


def changed(page, reference: np.ndarray, threshold: float, timeout: float = 30.0) -> np.ndarray:
    deadline = time.monotonic() + timeout
    while True:
        image = shot(page)
        if np.abs(image - reference).mean() > threshold or time.monotonic() > deadline:
            return image
        time.sleep(0.2)


def test_viewer_streams_orbits_and_renders(live_server, browser):
    http = httpx.Client(base_url=live_server.url, timeout=60)
    scene = http.post("/v1/scenes", files={"scene": ("viewer.json", tiny_json())}).json()
    page = browser.new_page(viewport={"width": 1400, "height": 900})
    errors = []
    page.on("pageerror", lambda error: errors.append(str(error)))
    page.goto(live_server.url + "/")
    page.wait_for_selector(f"#scenes option[value='{scene['id']}']", state="attached")
    page.select_option("#scenes", scene["id"])
    page.click("#start")
    shown = "() => { const i = document.getElementById('stream'); return i.naturalWidth > 0; }"
    page.wait_for_function(shown, timeout=60_000)
    first = shot(page)
    assert first.mean() > 5.0, "the stream is black"
    later = changed(page, first, 0.01)
    assert np.abs(later - first).mean() > 0.01, "the stream does not change"

    session_id = http.get("/v1/sessions").json()["data"][0]["id"]
    camera_before = http.get(f"/v1/sessions/{session_id}").json()["camera"]
    box = page.locator("#stream").bounding_box()
    x, y = box["x"] + box["width"] / 2, box["y"] + box["height"] / 2
    page.mouse.move(x, y)
    page.mouse.down()
    page.mouse.move(x + 200, y + 40, steps=12)
    page.mouse.up()
    page.wait_for_timeout(300)
    camera_after = http.get(f"/v1/sessions/{session_id}").json()["camera"]
    assert camera_after["position"] != camera_before["position"]
    orbited = changed(page, later, 10.0)
    assert np.abs(orbited - later).mean() > 10.0, "the drag did not change the view"

    page.mouse.move(x, y)
    page.mouse.wheel(0, 400)  # zoom out
    page.wait_for_timeout(300)
    zoomed = http.get(f"/v1/sessions/{session_id}").json()["camera"]
    assert np.linalg.norm(zoomed["position"]) > np.linalg.norm(camera_after["position"])

    page.wait_for_selector("#stats dt", timeout=10_000)
    assert "fps" in page.inner_text("#stats")

    page.select_option("#denoise", "fast")  # the toggle: the session denoises its stream
    deadline = time.monotonic() + 30
    while time.monotonic() < deadline:
        status = http.get(f"/v1/sessions/{session_id}").json()
        if status["stats"]["last_frame"].get("denoise"):
            break
        time.sleep(0.2)
    assert status["denoise"] == "fast" and status["stats"]["last_frame"]["denoise"], status
    page.wait_for_function(
        "() => document.getElementById('stats').innerText.includes('fast')", timeout=10_000
    )

    page.fill("#spp", "4")
    page.fill("#still-size", "64x36")
    page.click("#render")
    link = page.wait_for_selector("#download-png", timeout=60_000)
    png = http.get(link.get_attribute("href"))
    assert png.status_code == 200 and png.headers["content-type"] == "image/png"
    assert Image.open(io.BytesIO(png.content)).size == (64, 36)
    page.click("#stop")
    assert not errors, errors
