"""The video pipeline on realistic variants of the shared crash clips (re-encoded at another frame
rate, frozen stretches, ...), made inside each test from the real clips."""

from __future__ import annotations

from pathlib import Path

import av
import numpy as np

from conftest import DATA, need

CCD = DATA / "crash_ccd"


def _frames(clip: Path, count: int, start: int = 0, width: int = 640) -> list[np.ndarray]:
    """``count`` frames of ``clip`` from frame ``start`` (BGR), resized to ``width`` columns."""
    import cv2

    out = []
    with av.open(str(clip)) as c:
        for k, f in enumerate(c.decode(video=0)):
            if k < start:
                continue
            img = f.to_ndarray(format="bgr24")
            out.append(cv2.resize(img, (width, width * img.shape[0] // img.shape[1]), interpolation=cv2.INTER_AREA))
            if len(out) == count:
                break
    return out


def _write(path: Path, frames: list[np.ndarray], fps: int, crf: int = 23) -> Path:
    with av.open(str(path), "w") as c:
        s = c.add_stream("libx264", rate=fps)
        s.height, s.width = frames[0].shape[:2]
        s.pix_fmt, s.options = "yuv420p", {"crf": str(crf), "preset": "veryfast"}
        for img in frames:
            c.mux(s.encode(av.VideoFrame.from_ndarray(img, format="bgr24")))
        c.mux(s.encode())
    return path


def test_clip_reencoded_at_a_higher_frame_rate_or_with_a_frozen_stretch_is_one_shot(tmp_path):
    """A 10 fps CCD clip re-encoded at 30 fps repeats every frame 3 times: no cut at its crash (the
    adaptive cut detector once cut it there into shots), nor at a frozen stretch; a real cut is still
    found."""
    from deepcrashtest.video.shots import detect_shots

    src = _frames(need(CCD / "ccd_000053.mp4"), 20, start=22)  # the crash (labelled frame 33) in the middle
    up = _write(tmp_path / "fps30.mp4", [f for f in src for _ in range(3)], 30, crf=30)
    assert len(detect_shots(up)) == 1
    frozen = _write(tmp_path / "frozen.mp4", src[:12] + [src[12]] * 8 + src[12:], 10)
    assert len(detect_shots(frozen)) == 1
    other = _frames(need(CCD / "ccd_000330.mp4"), 15)
    comp = _write(tmp_path / "comp.mp4", [f for f in other + src for _ in range(3)], 30)
    assert [s.first_frame for s in detect_shots(comp)] == [0, 45]  # the join


def test_black_bars_are_found_and_the_default_camera_spans_the_picture(tmp_path):
    """A CCD clip pillarboxed and letterboxed (as online compilations re-frame them): the picture
    inside the bars is found (within 2 px), the default camera's field of view spans that picture and
    is centred on it; the clip itself (a snowy, dim day) has no bars."""
    import cv2

    from deepcrashtest.geometry.camera import camera_for_video, default_camera
    from deepcrashtest.video.bars import video_picture_area

    clip = need(CCD / "ccd_000053.mp4")
    src = _frames(clip, 8)  # 640x360
    pillar = [cv2.copyMakeBorder(f, 0, 0, 80, 80, cv2.BORDER_CONSTANT) for f in src]
    letter = [cv2.copyMakeBorder(f, 60, 60, 0, 0, cv2.BORDER_CONSTANT) for f in src]
    # within 2 px: the encoder's 4:2:0 chroma bleeds a pixel into the bar
    assert np.allclose(video_picture_area(_write(tmp_path / "p.mp4", pillar, 10, crf=35)), (80, 0, 720, 360), atol=2)
    assert np.allclose(video_picture_area(_write(tmp_path / "l.mp4", letter, 10, crf=35)), (0, 60, 640, 420), atol=2)
    assert video_picture_area(clip) == (0, 0, 1280, 720)
    cam = default_camera(800, 360, area=(80, 0, 720, 360))
    plain = default_camera(640, 360)
    assert (cam.fx, cam.cx - 80, cam.cy) == (plain.fx, plain.cx, plain.cy)
    assert camera_for_video(800, 360, area=(80, 0, 720, 360)) == cam  # what `extract` uses
    assert camera_for_video(800, 360, hfov_deg=60.0, area=(80, 0, 720, 360)).cx == 400.0


def test_camera_jolt_is_measured_inside_black_bars():
    """The camera's global motion (the jolt evidence of an ego crash) of a letterboxed CCD clip, given
    the picture inside the bars, equals that of the clip itself; over the whole frame the static bars
    pull the vertical shift toward zero (ccd_000132: its crash then found 0.7 s late)."""
    import cv2

    from deepcrashtest.perception.crash_detect import GlobalMotion

    src = _frames(need(CCD / "ccd_000132.mp4"), 12, start=24)  # around the labelled contact, frame 30
    pad = 60
    boxed = [cv2.copyMakeBorder(f, pad, pad, 0, 0, cv2.BORDER_CONSTANT) for f in src]
    plain, full, inside = GlobalMotion(), GlobalMotion(), GlobalMotion(area=(0, pad, 640, 360 + pad))
    for k, (a, b) in enumerate(zip(src, boxed, strict=True)):
        plain.update(k, a)
        full.update(k, b)
        inside.update(k, b)
    dy = [np.array(m.shift)[1:, 1] for m in (plain, full, inside)]
    assert np.allclose(dy[2], dy[0], atol=0.05)
    assert np.abs(dy[1]).mean() < 0.7 * np.abs(dy[0]).mean()  # what the bars did


def test_extract_gives_the_camera_the_picture_area_of_its_own_pass(tmp_path):
    """``extract`` finds the black bars from the first frames of its one decoding pass (no second
    decoding) and hands the picture area to a camera callable, as the CLI's ``camera_for_video``."""
    import cv2
    import pytest

    from deepcrashtest.pipeline.extract import run_extract

    src = _frames(need(CCD / "ccd_000053.mp4"), 10)  # 640x360
    video = _write(tmp_path / "l.mp4", [cv2.copyMakeBorder(f, 60, 60, 0, 0, cv2.BORDER_CONSTANT) for f in src], 10)
    seen: list[tuple[int, int, object]] = []

    class Seen(Exception):
        pass

    def camera(width: int, height: int, *, area: tuple[int, int, int, int] | None) -> None:
        seen.append((width, height, area))
        raise Seen  # what the camera is called with is all this test needs

    with pytest.raises(Seen):
        run_extract(video, tmp_path / "out", camera=camera, lanes=False, report=False, shots=False)  # type: ignore[arg-type]
    assert len(seen) == 1 and seen[0][:2] == (640, 480)
    assert np.allclose(seen[0][2], (0, 60, 640, 420), atol=2)  # type: ignore[arg-type]
    assert not (tmp_path / "out" / "tracks.csv").exists()  # nothing written by a failed run
