"""End-to-end: the viewer in a real Chromium (Playwright) on a KITTI 0008 scenario served by uvicorn."""

from __future__ import annotations

import os
import shutil
import socket
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from deepcrashtest.scenario import Scenario
from deepcrashtest.viz.server import SIM_UNAVAILABLE, _simulator, create_app

pytestmark = pytest.mark.browser

CHROMIUM = shutil.which("chromium") or ("/usr/bin/chromium" if Path("/usr/bin/chromium").exists() else None)
CHROMIUM_ARGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-background-networking",
    "--disable-component-update",
    "--no-first-run",
]
SAMPLE_VIDEO = Path(__file__).resolve().parents[1] / "examples" / "highway_sample.mp4"
AGENT, WAYPOINT = 9, 120


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class Server:
    """The viewer app under uvicorn in a thread, on a free loopback port."""

    def __init__(self, scenario: Path) -> None:
        import uvicorn

        self.port = _free_port()
        config = uvicorn.Config(create_app(scenario), host="127.0.0.1", port=self.port, log_level="warning")
        self.server = uvicorn.Server(config)
        self.thread = threading.Thread(target=self.server.run, daemon=True)

    def __enter__(self) -> str:
        self.thread.start()
        deadline = time.monotonic() + 20
        while not self.server.started:
            if time.monotonic() > deadline or not self.thread.is_alive():
                raise RuntimeError("viewer server did not start")
            time.sleep(0.02)
        return f"http://127.0.0.1:{self.port}"

    def __exit__(self, *exc: object) -> None:
        self.server.should_exit = True
        self.thread.join(timeout=10)


@pytest.fixture(scope="module")
def browser() -> Iterator[object]:
    if CHROMIUM is None:
        pytest.skip("chromium not found (apt-get install chromium); Playwright's own browser download does not work")
    from playwright.sync_api import sync_playwright

    with sync_playwright() as p:
        b = p.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
        yield b
        b.close()


@pytest.fixture()
def case(tmp_path, kitti8_raw) -> Path:
    d = tmp_path / "kitti_0008"
    d.mkdir()
    return kitti8_raw.save(d / "scenario.json")


def _open(browser, url: str):
    page = browser.new_page(viewport={"width": 1500, "height": 1000})
    errors: list[str] = []
    page.on("pageerror", lambda e: errors.append(str(e)))
    page.goto(url + "/")
    page.wait_for_function("window.dct && window.dct.ready", timeout=20000)
    return page, errors


def _zoom_to(page, vid: int, index: int, clicks: int = 4) -> tuple[float, float]:
    for _ in range(clicks):
        x, y = page.evaluate(f"window.dct.waypointClientXY({vid}, {index})")
        page.mouse.move(x, y)
        page.mouse.wheel(0, -500)
        page.wait_for_timeout(50)
    return tuple(page.evaluate(f"window.dct.waypointClientXY({vid}, {index})"))


def _status(page, prefix: str) -> str:
    page.wait_for_function(
        f"document.getElementById('status').textContent.startsWith({prefix!r})",
        timeout=20000,
    )
    return page.inner_text("#status")


def _check_screenshot(page, path: Path) -> None:
    """Screenshot the page; the canvas shows the road surface and the selected (yellow) vehicle."""
    import cv2

    page.screenshot(path=str(path))
    if os.environ.get("DCT_SCREENSHOT_DIR"):  # to look at it
        shutil.copyfile(path, Path(os.environ["DCT_SCREENSHOT_DIR"]) / path.name)
    box = page.locator("#bev").bounding_box()
    x0, y0 = int(box["x"]), int(box["y"])
    img = cv2.imread(str(path))[y0 : y0 + int(box["height"]), x0 : x0 + int(box["width"])]
    road = np.all(np.abs(img.astype(int) - [0x5E, 0x5B, 0x55]) <= 3, axis=2).mean()  # BGR of #555b5e
    selected = np.all(np.abs(img.astype(int) - [0x3B, 0xEB, 0xFF]) <= 40, axis=2).sum()  # BGR of #ffeb3b
    assert road > 0.1, road
    assert selected > 20, selected


def test_drag_a_waypoint_undo_redo_and_save(browser, case, tmp_path):
    original = Scenario.load(case)
    with Server(case) as url:
        page, errors = _open(browser, url)
        page.select_option("#vehicle", str(AGENT))
        page.fill("#falloff", "0.5")
        x, y = _zoom_to(page, AGENT, WAYPOINT)
        ppm = page.evaluate("window.dct.pixelsPerMetre()")
        assert ppm > 8, ppm  # zoomed in far enough to drag by a fraction of a metre
        page.mouse.move(x, y)
        page.mouse.down()
        page.mouse.move(x + 30, y - 20, steps=6)
        page.mouse.up()
        assert f"move_waypoint vehicle={AGENT} index={WAYPOINT}" in _status(page, "edited")
        _check_screenshot(page, tmp_path / "viewer.png")
        # undo puts the original back in the page, redo the edit
        page.click("#undo")
        _status(page, "undone")
        assert page.evaluate(f"window.dct.S.scenario.agents.find(a => a.id === {AGENT}).trajectory.x[{WAYPOINT}]") == (
            pytest.approx(original.vehicle(AGENT).trajectory.x[WAYPOINT])
        )
        page.click("#redo")
        _status(page, "redone")
        page.fill("#save-name", "kitti_0008_fixed.json")
        page.click("#save")
        assert _status(page, "saved") == "saved kitti_0008_fixed.json"
        # saving again is refused (the page's confirm is dismissed), the file stays as it was
        first = (case.parent / "kitti_0008_fixed.json").read_bytes()
        page.click("#save")
        assert "already exists" in _status(page, "save:")
        assert (case.parent / "kitti_0008_fixed.json").read_bytes() == first
        assert errors == []
        page.close()

    saved = Scenario.load(case.parent / "kitti_0008_fixed.json")
    old, new = original.vehicle(AGENT).trajectory, saved.vehicle(AGENT).trajectory
    dx, dy = new.x[WAYPOINT] - old.x[WAYPOINT], new.y[WAYPOINT] - old.y[WAYPOINT]
    # the mouse moved 30 px right and 20 px up: +x and +y in the world by pixels / (pixels per metre)
    assert dx == pytest.approx(30 / ppm, abs=1.5 / ppm)
    assert dy == pytest.approx(20 / ppm, abs=1.5 / ppm)
    assert new.t == old.t
    assert saved.provenance.history[0].startswith(f"move_waypoint vehicle={AGENT} index={WAYPOINT}")
    assert "saved by deepcrashtest view" in saved.provenance.history[-1]
    for v in original.vehicles():
        if v.id != AGENT:
            assert saved.vehicle(v.id) == v
    far = np.abs(np.asarray(old.t) - old.t[WAYPOINT]) > 0.7
    np.testing.assert_array_equal(np.asarray(new.x)[far], np.asarray(old.x)[far])
    assert Scenario.load(case) == original  # the opened file is untouched


def test_shift_fields_and_video_frame_in_sync(browser, case):
    shutil.copyfile(SAMPLE_VIDEO, case.parent / "annotated.mp4")
    with Server(case) as url:
        page, errors = _open(browser, url)
        assert page.is_hidden("#no-video")
        page.evaluate("window.dct.setTime(3.0)")
        page.wait_for_function(
            "document.getElementById('frame').complete && document.getElementById('frame').naturalWidth > 0"
            " && document.getElementById('frame').src.endsWith('t=3.000')"
        )
        assert page.evaluate("document.getElementById('frame').naturalWidth") == 960
        page.select_option("#vehicle", str(AGENT))
        page.fill("#d-lon", "0")
        page.fill("#d-lat", "1.25")
        page.click("#shift")
        assert "d_lat=+1.250" in _status(page, "edited")
        y = page.evaluate(f"window.dct.S.scenario.agents.find(a => a.id === {AGENT}).trajectory.y[0]")
        assert y != pytest.approx(Scenario.load(case).vehicle(AGENT).trajectory.y[0], abs=1.0)
        page.fill("#d-lat", "")
        page.click("#shift")
        assert "enter a number" in _status(page, "d-lat")
        assert errors == []
        page.close()


def test_no_video_shows_a_placeholder(browser, case):
    with Server(case) as url:
        page, _ = _open(browser, url)
        assert "no video" in page.inner_text("#no-video")
        assert page.is_hidden("#frame")
        page.close()


def test_simulate_shows_the_outcome(browser, case, tmp_path):
    if _simulator() is None:
        pytest.skip(SIM_UNAVAILABLE)
    with Server(case) as url:
        page, errors = _open(browser, url)
        page.click("#simulate")
        status = _status(page, "simulated")
        outcome = page.inner_text("#outcome")
        for key in ("collided", "collision time", "delta-v ego", "min distance"):
            assert key in outcome
        assert ("collision at" in status) == ("yes" in page.inner_text("#outcome dd[data-key='collided']"))
        assert page.evaluate("window.dct.S.sim.times.length") > 10
        _zoom_to(page, 0, 100, clicks=3)
        page.evaluate("window.dct.setTime(10.0)")
        _check_screenshot(page, tmp_path / "viewer_simulated.png")
        assert errors == []
        page.close()
