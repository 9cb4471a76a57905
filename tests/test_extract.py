"""`deepcrashtest extract` end to end on the bundled real clip, and its refusals."""

from __future__ import annotations

import json
from pathlib import Path

import av
import pandas as pd
import pytest

from deepcrashtest.cli import main
from deepcrashtest.perception.track import TRACK_COLUMNS
from test_cli import assert_one_line_error, run

SAMPLE = Path(__file__).resolve().parents[1] / "examples" / "highway_sample.mp4"


def test_extract_writes_tracks_and_h264_video(tmp_path):
    out = tmp_path / "ex"
    # 12 frames make no scenario (stage 2 would refuse them and write nothing): tracks and video only
    args = ["extract", str(SAMPLE), "-o", str(out), "--max-frames", "12", "--detect-every", "6", "--json"]
    args.append("--no-geometry")
    proc = run(*args)
    assert proc.returncode == 0, proc.stderr
    result = json.loads(proc.stdout)
    assert result["frames"] == 12 and result["width"] == 1280 and result["fps_video"] == 25.0
    assert result["fps_achieved"] > 0
    df = pd.read_csv(out / "tracks.csv")
    assert list(df.columns) == TRACK_COLUMNS
    with av.open(str(out / "annotated.mp4")) as c:
        s = c.streams.video[0]
        assert s.codec_context.name == "h264"
        assert sum(1 for _ in c.decode(s)) == 12
    before = (out / "tracks.csv").read_bytes()
    assert_one_line_error(run(*args), "already exists")
    assert (out / "tracks.csv").read_bytes() == before
    assert run(*args, "--force").returncode == 0


def _write(path: Path, data: bytes) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(data)
    return path


@pytest.mark.parametrize(
    ("make", "extra", "fragment"),
    [
        (lambda d: d / "missing.mp4", [], "no such"),
        (lambda d: _write(d / "empty.mp4", b""), [], "empty"),
        (lambda d: _write(d / "junk.mp4", b"\x00\x17junk" * 500), [], "not a readable"),
        (lambda d: _write(d / "imgs" / "notes.txt", b"no images here").parent, ["--fps", "10"], "no images"),
        (lambda d: SAMPLE, ["--fps", "-3"], "--fps"),
        (lambda d: SAMPLE, ["--detect-every", "0"], "--detect-every"),
        (lambda d: SAMPLE, ["--detector", "nope"], "unknown detector"),
    ],
    ids=["missing", "empty", "garbage", "no-images", "negative-fps", "detect-every-0", "bad-detector"],
)
def test_extract_bad_inputs(tmp_path, capsys, make, extra, fragment):
    video = make(tmp_path)
    assert main(["extract", str(video), "-o", str(tmp_path / "out"), *extra]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and fragment in err[0], err


DAD = Path(__file__).resolve().parents[2] / "shared" / "data" / "crash_dad" / "dad_000478.mp4"


def test_extract_crash_clip_end_to_end_writes_a_processed_scenario(tmp_path):
    """Real dashcam crash clip, unknown camera: one pass -> tracks, annotated video, raw + processed
    Scenario and report; the scenario's vehicles come from the tracks and the ego drives forward."""
    if not DAD.exists():
        pytest.skip(f"real data not found: {DAD}")
    from deepcrashtest.scenario import Scenario

    out = tmp_path / "dad"
    proc = run("extract", str(DAD), "-o", str(out), "--max-frames", "60", "--json")
    assert proc.returncode == 0, proc.stderr
    result = json.loads(proc.stdout)
    raw = Scenario.load(out / "scenario_raw.json")
    sc = Scenario.load(out / "scenario.json")
    assert raw.stage == "raw" and sc.stage == "processed"
    assert raw.source.fps == 20.0 and raw.source.sha256 is not None
    assert raw.source.frame_rate_note  # the paper's frame-rate caveat travels with the scenario
    tracks = pd.read_csv(out / "tracks.csv")
    assert {a.id for a in raw.agents} <= set(tracks["track_id"])  # agents are tracked vehicles
    assert len(sc.agents) >= 1 and result["agents"] == len(raw.agents)
    assert all(a.trajectory_class is not None for a in sc.agents)
    ego = sc.ego.trajectory.arrays()
    assert ego["x"][-1] > ego["x"][0]  # the dashcam car drives forward (world x)
    assert (out / "report.html").stat().st_size > 10_000
    with av.open(str(out / "annotated.mp4")) as c:
        assert sum(1 for _ in c.decode(video=0)) == 60


def test_extract_output_set_is_from_one_run_or_untouched(tmp_path):
    """A run that fails after the decoding pass writes nothing and exits 2, the previous set stays as it was;
    a forced run with fewer outputs removes the previous run's extra files (issue 18 items 2, 3, 12)."""
    if not DAD.exists():
        pytest.skip(f"real data not found: {DAD}")
    out = tmp_path / "x"
    first = run("extract", str(DAD), "-o", str(out), "--max-frames", "40", "--no-report", "--json")
    assert first.returncode == 0, first.stderr
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    assert {"tracks.csv", "scenario_raw.json", "scenario.json"} <= set(before)
    failed = run("extract", str(DAD), "-o", str(out), "--max-frames", "10", "--crash", "5:ego,999", "--force")
    assert failed.returncode == 2 and len(failed.stderr.strip().splitlines()) == 1, failed.stderr
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before  # untouched, no temp files left
    again = run("extract", str(DAD), "-o", str(out), "--max-frames", "10", "--no-geometry", "--force")
    assert again.returncode == 0, again.stderr
    assert sorted(p.name for p in out.iterdir()) == ["annotated.mp4", "tracks.csv"]
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]
