"""A variable-frame-rate video (a phone's recording, dropped frames): every frame keeps its own time through extract,
and the Scenario's frame <-> time mapping (``VideoSource.frame_times``) is what the crash, the fidelity and the viewer
read. A real crash clip (ccd_000053, 10 fps) written again without 13-15 of its 50
frames, each kept frame at its own timestamp."""

from __future__ import annotations

import json
from fractions import Fraction
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from conftest import DATA, need
from deepcrashtest.cli import main
from deepcrashtest.scenario import Scenario

#: Two ways of dropping frames: 15 of 50 in runs (on frame numbers the crash came 0.4 s early without the camera's
#: jolt), and 13 at random (seed 45 at 30 %, the labelled contact kept: extract's cut of the ego's speeds at the
#: crash rebuilt the scenario and lost its frame times).
DROPPED = (
    {3, 4, 9, 10, 11, 17, 18, 24, 25, 26, 31, 32, 36, 37, 38},
    {20, 21, 22, 24, 28, 29, 30, 32, 39, 41, 42, 46, 47},
)


@pytest.fixture(scope="module", params=DROPPED, ids=["runs", "random"])
def vfr_extract(request, tmp_path_factory) -> tuple[Path, list[float]]:
    import av

    with av.open(str(need(DATA / "crash_ccd" / "ccd_000053.mp4"))) as c:
        frames = [(f.to_ndarray(format="bgr24"), float(f.time)) for f in c.decode(video=0)]
    kept = [(img, t - frames[0][1]) for i, (img, t) in enumerate(frames) if i not in request.param]
    d = tmp_path_factory.mktemp("vfr")
    clip = d / "ccd_000053_vfr.mp4"
    with av.open(str(clip), "w") as out:
        s = out.add_stream("libx264", rate=10)
        s.height, s.width = kept[0][0].shape[:2]
        s.codec_context.time_base = Fraction(1, 1000)
        for img, t in kept:
            frame = av.VideoFrame.from_ndarray(np.ascontiguousarray(img), format="bgr24")
            frame.pts, frame.time_base = round(t * 1000), Fraction(1, 1000)
            out.mux(s.encode(frame))
        out.mux(s.encode())
    assert main(["--quiet", "extract", str(clip), "-o", str(d / "out")]) == 0
    return d / "out", [round(t, 3) for _, t in kept]


def test_a_variable_frame_rate_clip_keeps_each_frames_time(vfr_extract):
    """The raw and the processed scenario list every frame's own time (the mean rate, 35 frames over 4.9 s, is
    what ``fps`` says), and the crash found at a frame is placed at that frame's time, not at ``frame / fps``."""
    out, times = vfr_extract
    raw, processed = Scenario.load(out / "scenario_raw.json"), Scenario.load(out / "scenario.json")
    for sc in (raw, processed):
        assert sc.source.frame_times == pytest.approx(times, abs=1e-6)
        assert [sc.video_frame(sc.frame_time(k)) for k in range(len(times))] == list(range(len(times)))
    record = raw.provenance.parameters["crash_detection"]
    frame = int(record["frame"])
    assert record["video_time_s"] == pytest.approx(times[frame], abs=1e-4)
    assert abs(times[frame] - frame / raw.source.fps) > 0.05  # where frame / fps would have put it
    # found where it is in the clip as filmed (3.4 s; the label 3.3 s): on the file's frame numbers a dropped frame
    # doubled a step's motion, and with the frames dropped in runs the crash came at 3.0 s without the camera's jolt
    assert abs(record["video_time_s"] - 3.35) <= 0.1

    tracks = np.genfromtxt(out / "tracks.csv", delimiter=",", names=True)
    assert np.allclose(tracks["time"], np.asarray(times)[tracks["frame"].astype(int)], atol=1e-3)
    summary = json.loads((out / "scenario.json").read_text())["source"]
    assert summary["fps"] == pytest.approx((len(times) - 1) / times[-1], rel=0.05)


def test_an_even_grid_holds_a_variable_rate_videos_frames_at_their_times(kitti8_raw):
    """The crash cues' grid (``pipeline.crash.EvenGrid``): each frame at its time x the most common rate, a dropped
    frame a gap, never two frames on one grid frame; the camera's shift over a gap spread over its grid frames."""
    from deepcrashtest.pipeline.crash import EvenGrid

    times = [0.0, 0.05, 0.10, 0.25, 0.30, 0.45, 0.50, 0.5004]
    src = kitti8_raw.source.model_copy(update={"fps": 14.0, "frame_count": len(times), "frame_times": times})
    grid = EvenGrid.of(kitti8_raw.evolve(source=src))
    assert grid is not None and grid.fps == pytest.approx(20.0)
    assert grid.index.tolist() == [0, 1, 2, 5, 6, 9, 10, 11]
    frames, shifts = grid.motion((np.arange(8), np.full((8, 2), 6.0)))
    assert frames.tolist() == grid.index.tolist() and shifts[:, 0].tolist() == [6, 6, 6, 2, 6, 2, 6, 6]
    assert EvenGrid.of(kitti8_raw) is None
    burst = [0.0, 0.001, 0.002, 0.003, 0.5, 1.0]  # frames a millisecond apart: the grid stays at 4 x the mean rate
    src = src.model_copy(update={"fps": 5.0, "frame_count": len(burst), "frame_times": burst})
    grid = EvenGrid.of(kitti8_raw.evolve(source=src))
    assert grid is not None and grid.fps == pytest.approx(20.0) and grid.index.tolist() == [0, 1, 2, 3, 10, 20]


def test_the_monocular_filter_steps_by_the_frame_times_the_video_lists(kitti_root):
    """One rule says a video's rate varies: the file's (``VideoMeta.variable_frame_times`` -> the raw Scenario's
    ``source.frame_times``), which the monocular filter reads (``localize_tracks(frame_times=...)``) as the box
    headings do; it no longer judges the ego's times on its own. An even clock listed (in part: frames past the
    list continue at the mean rate) is the same as none; frames listed 0.2 s apart where they are 0.1 s move the
    tracks (KITTI 0001's boxes)."""
    from deepcrashtest.eval.kitti_mono import DEFAULT_MONO, ego_of, image_tracks, prepare_mono
    from deepcrashtest.geometry.mono3d import localize_tracks

    prep = prepare_mono(kitti_root, 1)
    tracks, ego = image_tracks(prep, DEFAULT_MONO), ego_of(prep.world)
    n = int(ego.frame.max()) + 1

    def states(times):
        out = localize_tracks(tracks, prep.camera, ego, prep.size, 10.0, DEFAULT_MONO.mono, frame_times=times)
        return out.sort_values(["track_id", "frame"], ignore_index=True)

    none = states(None)
    assert len(none) > 500
    pd.testing.assert_frame_equal(states(list(np.arange(n) / 10.0)), none)
    pd.testing.assert_frame_equal(states(list(np.arange(n // 2) / 10.0)), none)
    stretched = states(list(np.arange(n) / 5.0))
    moved = np.hypot(stretched["x"] - none["x"], stretched["y"] - none["y"])
    assert stretched[["track_id", "frame"]].equals(none[["track_id", "frame"]]) and float(moved.max()) > 0.5


def test_the_fidelity_scores_a_variable_rate_crash_at_its_labelled_frames_own_time(vfr_extract):
    """``evaluate fidelity`` with ccd_000053's label (its contact frame, 33, renumbered for the dropped frames): the
    labelled contact is at that frame's own time (3.3 s), not at its new number / the mean rate, and the crash's dt
    is measured from it."""
    out, times = vfr_extract
    label = json.loads((Path(__file__).resolve().parents[1] / "bench/labels/ccd_crashes.json").read_text())
    lab = dict(label["clips"]["ccd_000053"])
    kept = [round(k / 10, 3) for k in range(50)]
    frame = times.index(kept[lab["contact_frame"]])  # the contact frame is never dropped
    lab.update(video=str(out.parent / "ccd_000053_vfr.mp4"), contact_frame=frame, first_accident_frame=frame)
    labels = out.parent / "labels.json"
    labels.write_text(json.dumps(dict(label, clips={"ccd_000053_vfr": lab})))
    fid = out.parent / "fidelity"
    args = ["--quiet", "evaluate", "fidelity", str(out / "scenario.json"), "--labels", str(labels)]
    assert main([*args, "--clip", "ccd_000053_vfr", "-o", str(fid), "--no-video-out", "--force"]) == 0
    crash = json.loads((fid / "fidelity.json").read_text())["crash"]
    assert crash["label"]["video_time_s"] == pytest.approx(3.3, abs=1e-6)
    assert crash["dt_s"] == pytest.approx(crash["first_contact"]["video_time_s"] - 3.3, abs=1e-3)
    assert crash["reproduced"]
