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
from deepcrashtest.viz.server import create_app

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


def _open(browser, url: str, width: int = 1500, height: int = 1000):
    page = browser.new_page(viewport={"width": width, "height": height})
    errors: list[str] = []
    page.on("pageerror", lambda e: errors.append(str(e)))
    page.goto(url + "/")
    page.wait_for_function("window.dct && window.dct.ready", timeout=20000)
    return page, errors


def _zoom_to(page, vid: int, index: int, clicks: int = 4) -> tuple[float, float]:
    page.click("#fit")
    page.evaluate("document.getElementById('legend').open = false")
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
    assert road > 0.05, road
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


def test_shift_fields(browser, case):
    with Server(case) as url:
        page, errors = _open(browser, url)
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
    with Server(case) as url:
        page, errors = _open(browser, url)
        page.click("#simulate")
        status = _status(page, "simulated")
        outcome = page.inner_text("#outcome")
        for key in ("ego collided", "collision time", "delta-v ego", "min distance", "all collisions"):
            assert key in outcome
        assert ("ego collision at" in status) == ("yes" in page.inner_text("#outcome dd[data-key='ego collided']"))
        assert page.evaluate("window.dct.S.sim.times.length") > 10
        _zoom_to(page, 0, 100, clicks=3)
        page.evaluate("window.dct.setTime(10.0)")
        _check_screenshot(page, tmp_path / "viewer_simulated.png")
        assert errors == []
        page.close()


# --------------------------------------------------------------------------- time, markers, selection, layout
def _decoded_frames(path: Path) -> list[np.ndarray]:
    """Every frame of a video in order, decoded straight through with PyAV: the reference."""
    import av

    with av.open(str(path)) as c:
        return [f.to_ndarray(format="rgb24") for f in c.decode(video=0)]


def _shown(page, selector: str) -> np.ndarray:
    """RGB pixels of an element as the page shows it."""
    import cv2

    png = page.locator(selector).screenshot()
    return cv2.cvtColor(cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)


def _error(shown: np.ndarray, ref: np.ndarray) -> float:
    import cv2

    return float(np.abs(shown.astype(float) - cv2.resize(ref, shown.shape[1::-1], interpolation=cv2.INTER_AREA)).mean())


def test_the_shown_frame_is_the_annotated_videos_frame_at_the_mapped_time(browser, tmp_path, kitti8_raw):
    """Scenario time -> video frame by Scenario.video_frame only; before/after the video a state, no frozen frame."""
    d = tmp_path / "sync"
    d.mkdir()
    src = kitti8_raw.source.model_copy(update={"fps": 25.0, "frame_count": 200, "time_offset_s": 1.5})
    sc = kitti8_raw.evolve(source=src)  # scenario t = video t + 1.5 s; the sample clip: 200 frames at 25 fps
    sc.save(d / "scenario.json")
    shutil.copyfile(SAMPLE_VIDEO, d / "annotated.mp4")
    ref = _decoded_frames(SAMPLE_VIDEO)
    with Server(d / "scenario.json") as url:
        page, errors = _open(browser, url, 1280, 720)
        page.add_style_tag(content="#overlay, #video-caption { visibility: hidden !important; }")
        for t in (0.5, 1.5, 4.04, 6.52, 9.46, 9.5, 20.0):
            page.evaluate(f"window.dct.setTime({t})")
            k = sc.video_frame(t)
            assert page.evaluate(f"window.dct.videoFrame({t})") == k
            if k is None:
                state = "before the video" if t < 1.5 else "after the video"
                assert state in page.inner_text("#no-video") and page.is_hidden("#frame"), t
                continue
            page.wait_for_function(
                f"(() => {{ const f = document.getElementById('frame'); return !f.hidden && f.complete"
                f" && f.naturalWidth > 0 && f.src.endsWith('frame={k}'); }})()"
            )
            shown = _shown(page, "#frame")
            errs = {j: _error(shown, ref[j]) for j in (k - 25, k - 1, k, k + 1, k + 25) if 0 <= j < len(ref)}
            assert errs[k] < 6.0 and errs[k] == min(errs.values()), (t, k, errs)
        # stepping with the keyboard moves one video frame
        page.evaluate("window.dct.setTime(4.04)")
        page.focus("#bev")
        page.keyboard.press("ArrowRight")
        assert page.evaluate("window.dct.videoFrame(window.dct.S.t)") == sc.video_frame(4.04) + 1
        page.keyboard.press("Shift+ArrowLeft")
        assert page.evaluate("window.dct.S.t") == pytest.approx(sc.frame_time(sc.video_frame(4.04) + 1) - 1.0)
        assert errors == []
        page.close()


@pytest.fixture(scope="module")
def crash_case(tmp_path_factory, kitti8_raw) -> Path:
    """Processed KITTI 0008 cut to 4 agents, the parked van 3 moved into the ego's lane (the ego hits it), and a
    user-given collision between two other agents (a third-party crash)."""
    from deepcrashtest.scenario import Collision
    from deepcrashtest.trajectory.pipeline import process_scenario
    from deepcrashtest.viz.edit import shift_trajectory

    sc = process_scenario(kitti8_raw)
    sc = sc.evolve(agents=[a for a in sc.agents if a.id in (1, 2, 3, 9)])
    ego_y = np.interp(sc.vehicle(3).trajectory.x[0], sc.ego.trajectory.x, sc.ego.trajectory.y)
    sc = shift_trajectory(sc, 3, 0.0, float(ego_y - sc.vehicle(3).trajectory.y[0]))
    t = 8.0
    a, b = sc.vehicle(1).trajectory.state_at(t), sc.vehicle(2).trajectory.state_at(t)
    crash = Collision(time_s=t, other_id=1, agent_id=2, source="user", x=(a["x"] + b["x"]) / 2, y=(a["y"] + b["y"]) / 2)
    d = tmp_path_factory.mktemp("crash")
    return sc.evolve(collision=crash).save(d / "scenario.json")


def _red_cross_pixels(page, x: float, y: float, r: int = 14) -> int:
    """Pixels of the collision red (#ff1744) within ``r`` px of the page point (x, y)."""
    import cv2

    img = cv2.imdecode(np.frombuffer(page.screenshot(), np.uint8), cv2.IMREAD_COLOR).astype(int)
    patch = img[int(y) - r : int(y) + r, int(x) - r : int(x) + r]
    return int(np.all(np.abs(patch - [0x44, 0x17, 0xFF]) <= 30, axis=2).sum())


def test_collision_markers_jump_to_each_collision_and_the_cross_shows_only_then(browser, crash_case):
    sc = Scenario.load(crash_case)
    with Server(crash_case) as url:
        page, errors = _open(browser, url, 1280, 720)
        assert page.locator(".marker").count() == 1  # the scenario's own (user-given, third-party) collision
        page.click("#simulate")
        _status(page, "simulated")
        sim = page.evaluate("window.dct.S.sim.collisions")
        ego_hit = next(c for c in sim if 0 in c["vehicles"])
        assert set(ego_hit["vehicles"]) == {0, 3}
        assert page.locator(".marker").count() == 1 + len(sim)  # every pair, not only the first
        assert page.locator(".marker.sim").count() == len(sim)
        # delta-v of the ego from its collision entry, even where the metrics leave it out
        assert page.inner_text("#outcome dd[data-key='delta-v ego']") == f"{ego_hit['delta_v']['0']:.2f} m/s"
        # jump to the ego's collision: time, selection and the cross at the impact point for that pair only
        page.locator(f".marker.sim[data-pair='{'-'.join(map(str, ego_hit['vehicles']))}']").first.click()
        assert page.evaluate("window.dct.S.t") == pytest.approx(ego_hit["time"])
        assert page.evaluate("window.dct.S.selected") == 3
        px, py = page.evaluate(f"window.dct.clientXY({ego_hit['point'][0]}, {ego_hit['point'][1]})")
        page.evaluate("document.getElementById('legend').open = false")
        assert _red_cross_pixels(page, px, py) > 20
        page.evaluate(f"window.dct.setTime({ego_hit['time'] + 2.0})")
        assert _red_cross_pixels(page, px, py) == 0  # not at other times
        # the user-given third-party collision: its own marker, its pair, its time
        c = sc.collision
        page.locator(".marker.video").click()
        assert (
            page.evaluate("window.dct.S.t") == pytest.approx(c.time_s) and page.evaluate("window.dct.S.selected") == 1
        )
        px, py = page.evaluate(f"window.dct.clientXY({c.x}, {c.y})")
        assert _red_cross_pixels(page, px, py) > 20
        assert errors == []
        page.close()


def test_clicking_a_box_over_the_selected_path_selects_it(browser, crash_case):
    sc = Scenario.load(crash_case)
    with Server(crash_case) as url:
        page, errors = _open(browser, url, 1280, 720)
        van = sc.vehicle(3).trajectory
        t = 6.0  # the ego is a few metres behind the parked van
        page.check("#follow")
        page.evaluate(f"window.dct.setTime({t})")
        assert page.evaluate("window.dct.S.selected") == 0
        x, y = page.evaluate("window.dct.vehicleClientXY(3)")
        # the ego's waypoints run under the van's box: one is within grabbing distance of the click
        ego = sc.ego.trajectory
        near = (
            [
                i
                for i in range(len(ego.t))
                if np.hypot(*np.subtract(page.evaluate(f"window.dct.waypointClientXY(0, {i})"), (x, y))) < 6
            ]
            if abs(van.y[0] - np.interp(van.x[0], ego.x, ego.y)) < 0.5
            else []
        )
        assert near, "test setup: the van does not sit on the ego's path"
        page.mouse.click(x, y)
        assert page.evaluate("window.dct.S.selected") == 3
        assert page.evaluate("window.dct.S.t") == pytest.approx(t)  # no jump to a waypoint's time
        assert page.evaluate("window.dct.S.wp") is None
        # hovering shows the road user's read-out
        page.mouse.move(x + 1, y)
        hover = page.inner_text("#hover")
        assert "agent 3" in hover and "km/h" in hover and "heading" in hover
        assert errors == []
        page.close()


@pytest.mark.parametrize(("width", "height"), [(1280, 720), (1920, 1080)])
def test_layout_fits_the_window_and_opens_on_the_ego(browser, crash_case, tmp_path, width, height):
    shutil.copyfile(SAMPLE_VIDEO, crash_case.parent / "annotated.mp4")
    try:
        with Server(crash_case) as url:
            page, errors = _open(browser, url, width, height)
            assert page.evaluate("[document.documentElement.scrollWidth, document.documentElement.scrollHeight]") == [
                width,
                height,
            ]
            boxes = {s: page.locator(s).bounding_box() for s in ("#bev", "#timebar", "#video-wrap", "#play", "#time")}
            for sel, b in boxes.items():
                assert b["x"] >= 0 and b["y"] >= 0 and b["x"] + b["width"] <= width + 0.5, sel
                assert b["y"] + b["height"] <= height + 0.5, sel
            assert boxes["#bev"]["width"] >= 0.6 * width and boxes["#bev"]["height"] >= 0.75 * height
            for sel in ("#vehicle", "#falloff", "#fit", "#to-ego", "#follow", "#legend", "#speed"):
                assert page.is_visible(sel), sel
            # opens on the ego at a readable scale
            assert page.evaluate("window.dct.pixelsPerMetre()") >= 6
            ex, ey = page.evaluate("window.dct.vehicleClientXY(0)")
            bev = boxes["#bev"]
            assert bev["x"] < ex < bev["x"] + bev["width"] and bev["y"] < ey < bev["y"] + bev["height"]
            # a long message does not move anything
            page.evaluate("window.dct.setStatus('edit refused: ' + 'x'.repeat(600), true)")
            assert {s: page.locator(s).bounding_box() for s in boxes} == boxes
            assert page.is_visible("#toast")
            page.click("#fit")
            assert page.evaluate("window.dct.pixelsPerMetre()") < 6  # the whole 600 m drive
            page.check("#follow")
            page.evaluate("window.dct.setTime(20.0)")
            ex, ey = page.evaluate("window.dct.vehicleClientXY(0)")
            assert abs(ex - (bev["x"] + bev["width"] / 2)) < 2 and abs(ey - (bev["y"] + bev["height"] / 2)) < 2
            page.evaluate("document.getElementById('toast').hidden = true; window.dct.setTime(7.0)")
            page.click("#to-ego")
            shot = tmp_path / f"viewer_{width}x{height}.png"
            page.screenshot(path=str(shot))
            if os.environ.get("DCT_SCREENSHOT_DIR"):  # to look at it
                shutil.copyfile(shot, Path(os.environ["DCT_SCREENSHOT_DIR"]) / shot.name)
            assert errors == []
            page.close()
    finally:
        (crash_case.parent / "annotated.mp4").unlink()


def test_a_variable_frame_rate_videos_frames_map_by_their_own_times(browser, tmp_path, kitti8_raw):
    """Where the file's frame rate varies (``source.frame_times``), the page maps scenario time to a frame and a
    frame to its time as Scenario.video_frame / frame_time do (by the listed times, not frame / fps), and a step
    with the keyboard lands on the next frame's own time."""
    d = tmp_path / "vfr"
    d.mkdir()
    rng = np.random.default_rng(3)
    times = np.round(np.cumsum(np.r_[0.0, rng.choice([0.04, 0.08, 0.12], 199)]), 3).tolist()
    fps = (len(times) - 1) / times[-1]
    src = kitti8_raw.source.model_copy(
        update={"fps": fps, "frame_count": 200, "time_offset_s": 1.5, "frame_times": times}
    )
    sc = kitti8_raw.evolve(source=src)
    sc.save(d / "scenario.json")
    shutil.copyfile(SAMPLE_VIDEO, d / "annotated.mp4")
    with Server(d / "scenario.json") as url:
        page, errors = _open(browser, url, 1280, 720)
        for t in (0.5, 1.5, 1.52, 4.04, 6.52, 9.46, 1.5 + times[-1] + 0.5 / fps, 40.0):
            assert page.evaluate(f"window.dct.videoFrame({t})") == sc.video_frame(t), t
        for k in (0, 1, 57, 199, 200):
            assert page.evaluate(f"window.dct.frameTime({k})") == pytest.approx(sc.frame_time(k)), k
        page.evaluate("window.dct.setTime(4.04)")
        page.focus("#bev")
        page.keyboard.press("ArrowRight")
        k = sc.video_frame(4.04) + 1
        assert page.evaluate("window.dct.S.t") == pytest.approx(sc.frame_time(k))
        assert page.evaluate("window.dct.videoFrame(window.dct.S.t)") == k
        page.evaluate(f"window.dct.setTime({sc.frame_time(199)})")  # on past the last listed frame, frame by frame
        for k in (200, 201, 202):
            page.keyboard.press("ArrowRight")
            assert page.evaluate("window.dct.S.t") == pytest.approx(sc.frame_time(k)), k
        assert errors == []
        page.close()
