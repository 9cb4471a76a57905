"""The ego's speed read off a dashcam's GPS overlay (perception/overlay_speed.py, perception/text.py), against the
speeds read by eye on the shared crash clips (bench/labels/ego_speed_overlays.json)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from conftest import DATA, ROOT, need
from deepcrashtest.perception.overlay_speed import OverlaySpeed, OverlaySpeedReader, parse_speed
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


def _read(video: Path, max_s: float = 60.0) -> tuple[OverlaySpeed | None, int]:
    """The overlay speed of ``video`` read as ``extract`` reads it (its frames at extract's size), and how many
    frames the reader was given."""
    reader = make_text_reader()
    if reader is None:
        pytest.skip("no text reader installed (make setup installs rapidocr_onnxruntime)")
    overlay = OverlaySpeedReader(reader)
    offered = 0
    with open_video(video, max_width=DEFAULT_MAX_WIDTH) as source:
        for frame in source:
            if frame.time > max_s:
                break
            if overlay.wants(float(frame.time)):
                overlay.offer(int(frame.index), float(frame.time), frame.image)
                offered += 1
    return overlay.result(), offered


@pytest.mark.parametrize("clip", ["ccd_000014", "dad_000528"])
def test_the_speed_a_dashcam_burns_into_the_picture_is_read_as_labelled(clip: str):
    """Every 0.5 s of the two shared clips that show their GPS speed: each reading is the speed read by eye at that
    frame (ccd_000014 57-59 km/h, "58KM/H" among the date and GPS position; dad_000528 a crawl "006km/h" down to
    "000km/h"), and the place read is the overlay's bottom line."""
    label = json.loads(LABELS.read_text())["clips"][clip]
    found, offered = _read(need(DATA / label["video"]))
    assert found is not None
    assert len(found.kmh) >= offered - 1  # at most one sample unread
    truth = {f: r["kmh"] for r in label["readings"] for f in range(r["first_frame"], r["last_frame"] + 1)}
    checked = [(int(f), float(v)) for f, v in zip(found.frames, found.kmh, strict=True) if int(f) in truth]
    assert len(checked) >= 8
    for frame, kmh in checked:
        assert abs(kmh - truth[frame]) <= 1.0, (frame, kmh, truth[frame])
    assert found.unit == "km/h" and found.box[1] > 0.8 * 720


@pytest.mark.parametrize("video", ["crash_ccd/ccd_000487.mp4", "dashcam_udacity/highway_project_video.mp4"])
def test_a_clip_without_a_speed_in_its_picture_gives_none(video: str):
    """ccd_000487's overlay shows a brand, the date and the time, and a channel's caption sits on top; the Udacity
    highway clip has no overlay: neither gives a speed, and the reader stops looking after its first samples."""
    found, offered = _read(need(DATA / video), max_s=5.0)
    assert found is None
    assert offered == 3


def test_the_reader_stops_where_its_place_stops_showing_a_speed():
    """ccd_000014 with its overlay line painted over from frame 20 on (a text that was no overlay, passed by the
    camera, behaves alike): the readings before stay, the reader searches again at each miss and gives up after
    MAX_MISSES + 1 samples in a row, instead of reading every later frame."""
    from deepcrashtest.perception.overlay_speed import MAX_MISSES

    reader = make_text_reader()
    if reader is None:
        pytest.skip("no text reader installed (make setup installs rapidocr_onnxruntime)")
    overlay = OverlaySpeedReader(reader)
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
    found = overlay.result()
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
    overlay = OverlaySpeedReader(reader)
    for k, frame in enumerate(highway_frames):
        image = frame.copy()
        origin = (40, 35 if top else image.shape[0] - 20)
        cv2.putText(image, text, origin, cv2.FONT_HERSHEY_SIMPLEX, 0.8, (0, 0, 0), 4, cv2.LINE_AA)
        cv2.putText(image, text, origin, cv2.FONT_HERSHEY_SIMPLEX, 0.8, (255, 255, 255), 2, cv2.LINE_AA)
        overlay.offer(12 * k, 0.5 * k, image)
    found = overlay.result()
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
