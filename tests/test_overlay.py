"""The ego's speed and the clock read off a dashcam's overlay (perception/overlay.py, perception/text.py), against the
speeds read by eye on the shared crash clips (bench/labels/ego_speed_overlays.json)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from conftest import DATA, ROOT, need
from deepcrashtest.perception.overlay import OverlayReader, parse_clock, parse_speed
from deepcrashtest.perception.text import make_text_reader
from deepcrashtest.video.size import DEFAULT_MAX_WIDTH
from deepcrashtest.video.source import open_video

LABELS = ROOT / "bench" / "labels" / "ego_speed_overlays.json"


@pytest.mark.parametrize(
    ("text", "speed"),
    [
        ("58KM/H", (58.0, "km/h")),
        ("006km/h", (6.0, "km/h")),
        ("006km /h", (6.0, "km/h")),
        ("2012.08.08 09.16.26 044.881000 034.992400 59KM/H", (59.0, "km/h")),
        ("35 MPH", (35 * 1.609344, "mph")),
        ("120 kph", (120.0, "km/h")),
        ("58 км/ч", (58.0, "km/h")),
        ("92 KM/y", (92.0, "km/h")),  # км/ч as a Latin reader writes it
        ("92 KM/", (92.0, "km/h")),
        ("SPEED 92 K M/H", (92.0, "km/h")),  # a wide K's gap read as a space
        ("057MPH", (57 * 1.609344, "mph")),
        ("ODO 12 km", None),
        ("2015-08-21 08:10:32", None),  # a clock
        ("SPEED LIMIT 60", None),  # a number without its unit
        ("034.99240058KM/H", None),  # digits run into a coordinate's: not a word of their own
        ("09:16:58KM/H", None),
        ("58KM/H 61KM/H", None),  # two speeds: which one?
        ("999 km/h", None),
    ],
)
def test_a_speed_is_a_number_standing_alone_with_its_unit(text: str, speed: tuple[float, str] | None):
    got = parse_speed(text)
    if speed is None:
        assert got is None
    else:
        assert got is not None and got[0] == pytest.approx(speed[0]) and got[1] == speed[1]


def _read(video: Path, max_s: float = 60.0, slow: float = 1.0) -> tuple[OverlayReader, int]:
    """The overlay reader after ``video`` as ``extract`` reads it (its frames at extract's size; each frame's time
    stretched by ``slow``: the clip re-timed as a slow-motion copy would be), and how many frames it was given."""
    reader = make_text_reader()
    if reader is None:
        pytest.skip("no text reader installed (make setup installs rapidocr_onnxruntime)")
    overlay = OverlayReader(reader)
    offered = 0
    with open_video(video, max_width=DEFAULT_MAX_WIDTH) as source:
        for frame in source:
            time = slow * float(frame.time)
            if time > max_s:
                break
            if overlay.wants(time):
                overlay.offer(int(frame.index), time, frame.image)
                offered += 1
            else:
                overlay.see(int(frame.index), time, frame.image)
    return overlay, offered


@pytest.mark.parametrize("clip", ["ccd_000014", "dad_000528"])
def test_the_speed_a_dashcam_burns_into_the_picture_is_read_as_labelled(clip: str):
    """Every 0.5 s of the two shared clips that show their GPS speed: each reading is the speed read by eye at that
    frame (ccd_000014 57-59 km/h, "58KM/H" among the date and GPS position; dad_000528 a crawl "006km/h" down to
    "000km/h"), and the place read is the overlay's bottom line."""
    label = json.loads(LABELS.read_text())["clips"][clip]
    overlay, offered = _read(need(DATA / label["video"]))
    found = overlay.speed()
    assert found is not None
    assert len(found.kmh) >= offered - 1  # at most one sample unread
    truth = {f: r["kmh"] for r in label["readings"] for f in range(r["first_frame"], r["last_frame"] + 1)}
    checked = [(int(f), float(v)) for f, v in zip(found.frames, found.kmh, strict=True) if int(f) in truth]
    assert len(checked) >= 8
    for frame, kmh in checked:
        assert abs(kmh - truth[frame]) <= 1.0, (frame, kmh, truth[frame])
    assert found.unit == "km/h" and found.box[1] > 0.8 * 720


def test_a_clip_without_a_speed_in_its_picture_gives_none():
    """ccd_000487's overlay shows a brand, the date and the time, and a channel's caption sits on top: no speed (its
    small blurred clock digits read too unsteadily to time it: no clock rate either, rather than a wrong one); the
    Udacity highway clip has no overlay: nothing, and the reader stops looking after its first samples."""
    overlay, _ = _read(need(DATA / "crash_ccd" / "ccd_000487.mp4"), max_s=5.0)
    clock = overlay.clock()
    assert overlay.speed() is None and (clock is None or clock.slow_motion() is None)
    overlay, offered = _read(need(DATA / "dashcam_udacity" / "highway_project_video.mp4"), max_s=5.0)
    assert overlay.speed() is None and overlay.clock() is None and offered == 3


@pytest.mark.parametrize(
    ("text", "seconds"),
    [
        ("2012.08.08 09.16.26 044.881000", 9 * 3600 + 16 * 60 + 26),
        ("2015-08-21 08:10:32 006km/h", 8 * 3600 + 10 * 60 + 32),
        ("GARMIN 05-26-2019 11:45:03", 11 * 3600 + 45 * 60 + 3),
        ("2012.08.08", None),  # a date
        ("05-26-2019", None),
        ("09.1C:28", None),  # a misread digit
        ("25:10:10", None),
        ("10:00:00 11:00:00", None),
    ],
)
def test_a_clock_is_hours_minutes_and_seconds_standing_alone(text: str, seconds: int | None):
    got = parse_clock(text)
    assert (got is None) if seconds is None else (got == (float(seconds), "s"))


def test_a_slow_motion_copy_is_told_by_the_pictures_clock():
    """ccd_000014's clock (09:16:26 -> 09:16:30 over its 5 s, its digits often misread) runs in real time: the 95 %
    interval of its rate holds 1; the same frames re-timed at half speed (each frame shown twice as long, a
    compilation's slow-motion replay) make it run ~0.5 s per video second: told, whereas the images alone show only
    a slower drive. ccd_000053's clear digits tick exactly every 10 frames at 10 fps."""
    video = need(DATA / "crash_ccd" / "ccd_000014.mp4")
    real, _ = _read(video)
    clock = real.clock()
    assert clock is not None and clock.slow_motion() is None
    rate = clock.rate()
    assert rate is not None and rate[1] <= 1.0 <= rate[2]
    slow, _ = _read(video, slow=2.0)
    clock = slow.clock()
    assert clock is not None
    assert clock.slow_motion() == pytest.approx(0.5, abs=0.1)
    assert clock.real_time_fps(5.0) == pytest.approx(10.0, rel=0.1)  # 5 fps play it at half speed: 10 fps filmed
    assert real.clock().real_time_fps(10.0) is None  # type: ignore[union-attr]
    assert slow.speed() is not None  # the speed is read all the same
    clear, _ = _read(need(DATA / "crash_ccd" / "ccd_000053.mp4"))
    clock = clear.clock()
    assert clock is not None and clock.rate() == pytest.approx((1.0, 1.0, 1.0))
    assert np.allclose(np.diff(clock.ticks_t), 1.0)


@pytest.mark.parametrize("clip", ["dad_000478", "dad_000493", "dad_000550"])
def test_the_dad_clips_are_played_slower_than_they_were_filmed(clip: str):
    """The DAD clips are stored at 20 fps, but their dashcams' clocks tick every ~24-25 frames: footage of ~25 fps
    played at 0.8x (the dataset's frame-rate caveat, measured). Every speed of their scenarios is ~20 % low."""
    overlay, _ = _read(need(DATA / "crash_dad" / f"{clip}.mp4"))
    clock = overlay.clock()
    assert clock is not None
    slow = clock.slow_motion()
    assert slow is not None and 0.75 < slow < 0.85
    assert 23.0 < float(np.median(np.diff(clock.ticks_t))) * 20.0 < 26.0  # frames per clock second
    assert 24.0 <= clock.real_time_fps(20.0) <= 25.0  # type: ignore[operator]  # the frame rate it was filmed at


def test_the_reader_stops_where_its_place_stops_showing_a_speed():
    """ccd_000014 with its overlay line painted over from frame 20 on (a text that was no overlay, passed by the
    camera, behaves alike): the readings before stay, the reader searches again at each miss and gives up after
    MAX_MISSES + 1 samples in a row, instead of reading every later frame."""
    from deepcrashtest.perception.overlay import MAX_MISSES

    reader = make_text_reader()
    if reader is None:
        pytest.skip("no text reader installed (make setup installs rapidocr_onnxruntime)")
    overlay = OverlayReader(reader)
    offered = []
    with open_video(need(DATA / "crash_ccd" / "ccd_000014.mp4"), max_width=DEFAULT_MAX_WIDTH) as source:
        for frame in source:
            if not overlay.wants(float(frame.time)):
                continue
            image = frame.image.copy()
            if frame.index >= 20:
                image[image.shape[0] - 60 :] = 40
            overlay.offer(int(frame.index), float(frame.time), image)
            offered.append(int(frame.index))
    found = overlay.speed()
    assert found is not None and found.frames.tolist() == [0, 5, 10, 15]
    assert offered == [0, 5, 10, 15] + [20 + 5 * k for k in range(MAX_MISSES + 1)]


@pytest.fixture(scope="module")
def highway_frames() -> list:
    """Four frames 0.5 s apart of the Udacity highway clip (no overlay of its own)."""
    from itertools import islice

    with open_video(need(DATA / "dashcam_udacity" / "highway_project_video.mp4")) as source:
        return [f.image for f in islice(source, 48) if f.index % 12 == 0]


@pytest.mark.parametrize(
    ("text", "top", "kmh"),
    [
        ("92KM/H", False, 92.0),
        ("057 MPH", False, 57 * 1.609344),
        ("92 km/h", True, 92.0),
        ("SPEED 92 KM/H", False, 92.0),
        ("92kph", True, 92.0),
        ("2019/01/05 12:33:10 N55.7512 E37.6184 92KM/H", False, 92.0),
    ],
)
def test_other_dashcams_speed_formats_are_read(highway_frames: list, text: str, top: bool, kmh: float):
    """Speed overlays as other dashcams write them (units, a label, the top of the picture, a long GPS line), drawn
    white on black onto a real drive: read at every sample, in km/h."""
    import cv2

    reader = make_text_reader()
    if reader is None:
        pytest.skip("no text reader installed (make setup installs rapidocr_onnxruntime)")
    overlay = OverlayReader(reader)
    for k, frame in enumerate(highway_frames):
        image = frame.copy()
        origin = (40, 35 if top else image.shape[0] - 20)
        cv2.putText(image, text, origin, cv2.FONT_HERSHEY_SIMPLEX, 0.8, (0, 0, 0), 4, cv2.LINE_AA)
        cv2.putText(image, text, origin, cv2.FONT_HERSHEY_SIMPLEX, 0.8, (255, 255, 255), 2, cv2.LINE_AA)
        overlay.offer(12 * k, 0.5 * k, image)
    found = overlay.speed()
    assert found is not None and found.kmh == pytest.approx([kmh] * len(highway_frames))
    assert (found.box[1] < 100) == top


def test_a_known_speed_that_would_make_no_dashcams_lens_drives_the_ego_instead():
    """An image ego-motion reading 8 km/h (a snowy road read as a crawl) against an overlay's 90 km/h: the focal
    length that would reconcile them (11x the assumed 640 px: a 10 deg field of view) is no dashcam's, so the image
    ego-motion's speed is what is off: no focal length from it, the user is told, and the ego drives at the overlay's
    speed along its own headings. 30 km/h against the same reading (3.75x: 30 deg, a cropped dashcam clip like
    ccd_000014's 21 deg) gives the focal length; the readings are matched over the frames where both move."""
    import numpy as np

    from deepcrashtest.geometry.egomotion import EgoMotion
    from deepcrashtest.geometry.known_speed import KnownSpeed, ego_speed_term, with_known_speed
    from deepcrashtest.scenario import Camera

    t = np.arange(50) / 10.0
    speed = np.full(50, 8.0 / 3.6)
    speed[:10] = 0.0  # standing at first: not compared
    yaw = np.linspace(0.0, 0.5, 50)
    ego = EgoMotion(np.arange(50), t, np.cumsum(speed) / 10, np.zeros(50), yaw, speed, np.zeros(50), np.ones(50, bool))
    camera = Camera(fx=640.0, fy=640.0, cx=640.0, cy=360.0, height_m=1.3)
    notes: list[str] = []
    warnings: list[str] = []
    overlay = KnownSpeed(np.array([0.0, 0.5, 1.0, 4.5]), np.array([0.0, 0.0, 90.0, 90.0]) / 3.6, "overlay", "90 km/h")
    assert ego_speed_term(ego, camera, overlay, True, 1.3, notes, warnings, 1280) == (None, True)
    assert "would make the field of view 10 deg" in notes[-1] and "no dashcam's" in warnings[-1]
    driven = with_known_speed(ego, overlay)
    assert driven.speed[-1] == pytest.approx(25.0) and driven.speed[5] == pytest.approx(0.0)
    steps = np.hypot(np.diff(driven.x), np.diff(driven.y))
    assert steps[-1] == pytest.approx(2.5) and np.allclose(
        np.arctan2(np.diff(driven.y), np.diff(driven.x))[20:], 0.5 * (yaw[21:] + yaw[20:-1])
    )
    slower = KnownSpeed(overlay.times_s, overlay.mps / 3.0, "overlay", "30 km/h")
    found, replace_speed = ego_speed_term(ego, camera, slower, True, 1.3, notes, warnings, 1280)
    assert found is not None and found[0] == pytest.approx(640.0 * 30.0 / 8.0) and found[2] == 40 and not replace_speed


def test_extract_retimes_a_video_whose_clock_runs_slower_than_its_frame_rate(tmp_path):
    """``extract`` of dad_000478 (a 20 fps file, its dashcam's clock ticking every ~25 frames) runs at the clock's
    25 fps: the scenario's frame rate, its provenance (``time_base``: the clock's rate at the file's 20 fps, 0.75-0.85,
    95 % interval below 0.95) and a warning say so; the crash is found at the same frame, ~0.8x the file's time.
    ``retime=False`` keeps the file's 20 fps, with the clock's rate in the provenance and a warning giving the
    ``--fps`` that plays it in real time. The fidelity overlay video of the re-timed scenario plays at 25 fps."""
    import av
    import pandas as pd

    from deepcrashtest.eval.fidelity import evaluate_fidelity
    from deepcrashtest.pipeline.extract import run_extract
    from deepcrashtest.scenario import Scenario
    from deepcrashtest.viz.fidelity_video import write_fidelity_video

    if make_text_reader() is None:
        pytest.skip("no text reader installed (make setup installs rapidocr_onnxruntime)")
    video = need(DATA / "crash_dad" / "dad_000478.mp4")
    found = run_extract(video, tmp_path / "clock", annotate=False, report=False)
    raw = Scenario.load(tmp_path / "clock" / "scenario_raw.json")
    assert raw.source.fps == 25.0
    base = raw.provenance.parameters["time_base"]
    assert base["fps"] == 25.0 and base["file_fps"] == 20.0 and base["source"] == "overlay clock"
    assert 0.75 < base["clock_rate_at_file_fps"] < 0.85 and base["interval_95"][1] < 0.95
    said = [w for w in raw.warnings if w.startswith("the picture's clock")]
    assert len(said) == 1 and "extracted at 25 fps" in said[0] and "--no-retime" in said[0], said
    tracks = pd.read_csv(tmp_path / "clock" / "tracks.csv")  # the overlay video plays at the clock's rate too
    overlay = write_fidelity_video(raw, evaluate_fidelity(raw, tracks), None, video, tracks, tmp_path / "f.mp4", None,
                                   max_frames=3)  # fmt: skip
    with av.open(overlay["path"]) as c:
        assert float(c.streams.video[0].average_rate) == 25.0 and c.streams.video[0].frames == 3
    kept = run_extract(video, tmp_path / "file", annotate=False, report=False, retime=False)
    raw = Scenario.load(tmp_path / "file" / "scenario_raw.json")
    assert raw.source.fps == 20.0 and "time_base" not in raw.provenance.parameters
    clock = raw.provenance.parameters["overlay_clock"]
    assert 0.75 < clock["rate"] < 0.85 and clock["interval_95"][1] < 0.95 and clock["ticks"] >= 3
    said = [w for w in raw.warnings if w.startswith("the picture's clock")]
    assert len(said) == 1 and "slow motion" in said[0] and "--fps 25 plays it in real time" in said[0], said
    crashes = found["crash_detection"], kept["crash_detection"]
    assert crashes[0]["frame"] == crashes[1]["frame"], crashes
    assert crashes[0]["video_time_s"] == pytest.approx(0.8 * crashes[1]["video_time_s"], abs=0.01)


def test_a_long_slow_motion_video_is_retimed_as_soon_as_its_clock_is_read(tmp_path):
    """ccd_000053's 50 frames (10 fps, a clock ticking every 10 frames) stored at 4 fps: 12.5 s of video, 0.4x real
    time. Its clock is read by 10 s into the first pass, which stops there (not after its last frame); the extraction
    runs again at the camera's 10 fps: a time base of 10 fps (clock rate 0.4 at the file's 4 fps), and the crash
    detection, whose rules are in seconds, finds the labelled contact (frame 33, bench/labels/ccd_crashes.json) within
    a frame, as on the original clip; at the file's 4 fps (``retime=False``) it found frame 31."""
    import av

    from deepcrashtest.datasets.crash_labels import load_crash_labels
    from deepcrashtest.pipeline.extract import run_extract
    from deepcrashtest.scenario import Scenario

    if make_text_reader() is None:
        pytest.skip("no text reader installed (make setup installs rapidocr_onnxruntime)")
    with av.open(str(need(DATA / "crash_ccd" / "ccd_000053.mp4"))) as src:
        frames = [f.to_ndarray(format="bgr24") for f in src.decode(video=0)]
    slow = tmp_path / "slow.mp4"
    with av.open(str(slow), "w") as out:
        stream = out.add_stream("libx264", rate=4)
        stream.height, stream.width = frames[0].shape[:2]
        stream.pix_fmt, stream.options = "yuv420p", {"crf": "18", "preset": "veryfast"}
        for img in frames:
            out.mux(stream.encode(av.VideoFrame.from_ndarray(img, format="bgr24")))
        out.mux(stream.encode())
    found = run_extract(slow, tmp_path / "clock", annotate=False, report=False)
    raw = Scenario.load(tmp_path / "clock" / "scenario_raw.json")
    base = raw.provenance.parameters["time_base"]
    assert raw.source.fps == 10.0 and base["fps"] == 10.0 and base["file_fps"] == 4.0, base
    assert base["clock_rate_at_file_fps"] == pytest.approx(0.4, abs=0.02)
    label = load_crash_labels(ROOT / "bench" / "labels" / "ccd_crashes.json")["ccd_000053"]
    crash = found["crash_detection"]
    assert abs(crash["frame"] - label.contact_frame) <= 1, crash
    assert crash["video_time_s"] == pytest.approx(crash["frame"] / 10.0)


def test_a_clock_followed_by_text_is_read_again_without_the_next_words_glyph():
    """dad_000512's overlay line "2015/09/18 - 07:53:27 -VicoTag7: Vico-WF1" (found at full size): the clock's box read
    again ends a quarter glyph past its seconds (``_Field.room``), not a whole glyph, which took in the "-V" after it
    (read "07:53:27-1": no clock). Every 10th frame's crop then reads a running clock, 07:53:27 -> 07:53:30."""
    from deepcrashtest.perception.overlay import BAND, _clock_match, _value_box

    reader = make_text_reader()
    if reader is None:
        pytest.skip("no text reader installed (make setup installs rapidocr_onnxruntime)")
    with open_video(need(DATA / "crash_dad" / "dad_000512.mp4"), max_width=DEFAULT_MAX_WIDTH) as source:
        frames = [f.image for f in source if f.index % 10 == 0]
    band_h = int(round(BAND * frames[0].shape[0]))
    y0 = frames[0].shape[0] - band_h
    line = next(x for x in reader.find(frames[1][y0:]) if parse_clock(x.text) is not None)

    def clocks(room: float) -> list[float | None]:
        x1, y1, x2, y2 = _value_box(line, _clock_match, frames[0].shape[1], band_h, room)
        read = [reader.read(img[y0 + y1 : y0 + y2, x1:x2]) for img in frames]
        return [(parse_clock(text) or (None,))[0] if score >= 0.7 else None for text, score in read]

    tight = clocks(0.25)
    assert None not in tight and tight[0] == 28407.0 and tight[-1] == 28410.0, tight
    assert all(b - a in (0.0, 1.0) for a, b in zip(tight, tight[1:], strict=False))
    assert clocks(1.0).count(None) >= len(frames) // 2  # the whole glyph after it: most crops read no clock


class _BrokenReader:
    """A text reader plug-in whose model cannot run (every call raises, as a broken model file would)."""

    def detect(self, image: np.ndarray) -> int:
        raise RuntimeError("model file truncated")

    def find(self, image: np.ndarray) -> list:
        raise RuntimeError("model file truncated")

    def read(self, image: np.ndarray) -> tuple[str, float]:
        raise RuntimeError("model file truncated")


def test_a_text_reader_that_fails_stops_the_overlay_not_the_extraction(tmp_path, monkeypatch):
    """The overlay is an extra: a text reader plug-in that raises stops the reading (no speed, no clock, no more
    frames wanted) and says why; ``extract`` of ccd_000014 still writes its scenario, on the images' scale, with a
    warning naming the failure."""
    from deepcrashtest.perception import text
    from deepcrashtest.pipeline.extract import run_extract
    from deepcrashtest.scenario import Scenario

    overlay = OverlayReader(_BrokenReader())
    image = np.zeros((720, 1280, 3), np.uint8)
    overlay.offer(0, 0.0, image)
    assert overlay.failed == "RuntimeError: model file truncated"
    assert not overlay.wants(0.5) and overlay.speed() is None and overlay.clock() is None
    monkeypatch.setattr(text, "make_text_reader", lambda name="rapidocr": _BrokenReader())
    video = need(DATA / "crash_ccd" / "ccd_000014.mp4")
    run_extract(video, tmp_path / "out", annotate=False, report=False, max_frames=30)
    raw = Scenario.load(tmp_path / "out" / "scenario_raw.json")
    assert any("text reader failed (RuntimeError: model file truncated)" in w for w in raw.warnings)
    assert raw.camera.fy < 2000  # the images' scale: no overlay speed
