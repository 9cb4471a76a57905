"""``deepcrashtest batch`` on real KITTI scenarios: manifest, failures, --resume, and kill -9."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from deepcrashtest.errors import UserError
from deepcrashtest.scenario import Scenario

sim = pytest.importorskip("deepcrashtest.sim")
if not hasattr(sim, "simulate_batch"):
    pytest.skip("the simulator (deepcrashtest.sim.simulate_batch) is not in this build", allow_module_level=True)

from deepcrashtest.pipeline.batch import list_inputs, process_video, read_manifest, run_batch  # noqa: E402
from deepcrashtest.search.run import SearchConfig  # noqa: E402
from deepcrashtest.sim.testcases import meet_ego  # noqa: E402
from deepcrashtest.video.source import open_video  # noqa: E402

SMALL = ["--starts", "4", "--noise-variants", "2", "--method", "random", "--duration", "13"]
#: Oncoming cars of KITTI 0008 and a time inside each one's observed span (s).
CRASHES = {"a_car10": (10, 8.8), "b_car11": (11, 9.5), "c_car12": (12, 11.0), "d_car13": (13, 12.0)}


@pytest.fixture(scope="module")
def inputs(kitti8_raw, tmp_path_factory) -> Path:
    """Four real crash scenarios (KITTI 0008, one oncoming car shifted onto the ego each) + one broken file."""
    d = tmp_path_factory.mktemp("inputs")
    for name, (agent, t) in CRASHES.items():
        meet_ego(kitti8_raw, agent, t).save(d / f"{name}.json")
    (d / "e_broken.json").write_text('{"schema_version": "1.0", "name": 3}')
    (d / "notes.txt").write_text("not an input")
    return d


def batch(*args: str) -> subprocess.Popen[str]:
    cmd = [sys.executable, "-m", "deepcrashtest.cli", "--quiet", "batch", *args]
    return subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def test_lists_videos_and_scenarios_only(inputs, tmp_path):
    assert [p.name for p in list_inputs(inputs)] == [*(f"{n}.json" for n in CRASHES), "e_broken.json"]
    with pytest.raises(UserError, match="no videos"):
        list_inputs(tmp_path)


def test_kill_9_loses_nothing_finished_and_resume_completes(inputs, tmp_path):
    out = tmp_path / "out"
    proc = batch(str(inputs), "-o", str(out), *SMALL)
    manifest = out / "manifest.json"
    deadline = time.time() + 240
    done: list[str] = []
    while time.time() < deadline and proc.poll() is None:
        if manifest.exists():
            items = json.loads(manifest.read_text())["items"]  # atomic writes: always whole JSON
            done = [n for n, e in items.items() if e["status"] == "done"]
            if done:
                break
        time.sleep(0.02)
    assert proc.poll() is None, f"batch ended before it could be killed: {proc.communicate()}"
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait(timeout=30)
    assert proc.returncode == -signal.SIGKILL
    killed = read_manifest(manifest)["items"]
    finished = {n for n, e in killed.items() if e["status"] == "done"}
    assert finished and len(finished) < len(CRASHES), killed
    stamps = {}
    for n in finished:  # everything a finished input wrote is complete
        s = json.loads((out / n / "search" / "summary.json").read_text())
        assert s["methods"]["random"]["simulations"] == 8
        assert len((out / n / "search" / "results.csv").read_text().splitlines()) == 1 + 1 + 8
        stamps[n] = (out / n / "search" / "summary.json").stat().st_mtime_ns
    # without --resume the batch refuses to touch the existing output
    again = batch(str(inputs), "-o", str(out), *SMALL)
    _, err = again.communicate(timeout=120)
    assert again.returncode == 2 and "--resume" in err
    resumed = batch(str(inputs), "-o", str(out), *SMALL, "--resume", "--json")
    stdout, err = resumed.communicate(timeout=300)
    assert resumed.returncode == 1, err  # one input (e_broken) failed: the batch finished, the exit code says so
    assert "1 input(s) failed" in err
    res = json.loads(stdout)
    assert res["done"] == len(CRASHES) and res["failed"] == 1 and res["skipped"] == len(finished)
    assert "e_broken" in res["errors"] and "name" in res["errors"]["e_broken"]
    items = read_manifest(manifest)["items"]
    for n in CRASHES:
        assert items[n]["status"] == "done" and items[n]["result"]["original_collided"] is True
    for n, stamp in stamps.items():  # finished inputs were skipped, not redone
        assert (out / n / "search" / "summary.json").stat().st_mtime_ns == stamp


def _cut(clip: Path, dest: Path, frames: int, codec: str = "libx264") -> Path:
    """The first ``frames`` frames of a real clip, re-encoded with ``codec`` (a short real video for a fast test)."""
    import av

    with av.open(str(clip)) as src, av.open(str(dest), "w") as out:
        stream = out.add_stream(codec, rate=20)
        stream.width, stream.height, stream.pix_fmt = 640, 360, "yuv420p"
        for i, frame in enumerate(src.decode(video=0)):
            if i >= frames:
                break
            rgb = frame.to_ndarray(width=640, height=360, format="rgb24")
            for packet in stream.encode(av.VideoFrame.from_ndarray(rgb, format="rgb24")):
                out.mux(packet)
        for packet in stream.encode():
            out.mux(packet)
    return dest


def test_batch_extracts_real_videos_and_records_a_broken_one(kitti_root, tmp_path):
    dad = kitti_root.parent / "crash_dad"
    if not dad.is_dir():
        pytest.skip(f"real data not found: {dad}")
    folder = tmp_path / "videos"
    folder.mkdir()
    clip = _cut(sorted(dad.glob("*.mp4"))[0], folder / "crash.mp4", 50)
    (folder / "broken.mp4").write_bytes(clip.read_bytes()[:4000])  # a cut-off recording
    cfg = SearchConfig(starts=2, noise_variants=2, method="random", video=False, max_scenarios=1)
    res = run_batch(folder, tmp_path / "out", cfg)
    assert res["done"] == 1 and res["failed"] == 1
    assert "broken" in res["errors"] and "crash" not in res["errors"]
    extracted = Scenario.load(tmp_path / "out" / "crash" / "extract" / "scenario.json")
    assert extracted.stage == "processed" and extracted.source.fps == 20.0
    summary = json.loads((tmp_path / "out" / "crash" / "search" / "summary.json").read_text())
    assert summary["methods"]["random"]["simulations"] == 4
    entry = read_manifest(tmp_path / "out" / "manifest.json")["items"]["crash"]["result"]
    crash = extracted.collision
    assert entry["crash"] == (
        None
        if crash is None
        else {"participants": list(crash.participants), "time_s": crash.time_s, "source": crash.source}
    )
    assert set(entry["plausibility"]) == {
        "vehicles_with_half_turns",
        "over_turning_share",
        "over_traction_share",
        "sliding_share",
        "overlapping_pairs",
    }
    with pytest.raises(UserError):
        process_video(folder / "broken.mp4", tmp_path / "one", cfg)


def test_a_folder_lists_the_videos_phones_and_dashcams_write(kitti_root, tmp_path):
    """``batch`` takes a folder's WebM (VP9), MPEG transport stream (a dashcam's ``.TS``) and 3GP clips as ``extract``
    does; before, only ``*.mp4 *.mov *.avi *.mkv`` were read and these were left out without a word."""
    dad = kitti_root.parent / "crash_dad"
    if not dad.is_dir():
        pytest.skip(f"real data not found: {dad}")
    clip = sorted(dad.glob("*.mp4"))[0]
    written = [
        _cut(clip, tmp_path / "a.webm", 6, "libvpx-vp9"),
        _cut(clip, tmp_path / "b.TS", 6, "mpeg2video"),
        _cut(clip, tmp_path / "c.3gp", 6),
    ]
    (tmp_path / "notes.txt").write_text("not an input")
    assert list_inputs(tmp_path) == written
    for video in written:
        with open_video(video) as source:
            assert sum(1 for _ in source) == 6


def test_two_inputs_at_once_write_what_one_at_a_time_writes(inputs, tmp_path):
    """``--jobs 2`` (two inputs at once, each in its own process, the search's processes shared) writes the same
    results as ``--jobs 1``, and records the broken input the same way."""
    runs = {}
    for jobs in ("1", "2"):
        out = tmp_path / f"jobs{jobs}"
        proc = batch(str(inputs), "-o", str(out), *SMALL, "--jobs", jobs, "--json")
        stdout, err = proc.communicate(timeout=300)
        assert proc.returncode == 1, err  # e_broken failed, the others done
        res = json.loads(stdout)
        assert res["done"] == len(CRASHES) and res["failed"] == 1
        runs[jobs] = (out, res, read_manifest(out / "manifest.json")["items"])
    (one, res1, items1), (two, res2, items2) = runs["1"], runs["2"]
    assert res1["errors"] == res2["errors"]
    for n in CRASHES:
        assert items2[n]["status"] == "done" and items2[n]["result"] == items1[n]["result"]
        assert (one / n / "search" / "results.csv").read_bytes() == (two / n / "search" / "results.csv").read_bytes()
    refused = ((["--jobs", "0"], "--jobs must be 1-64"), (["--jobs", "2", "--engine", "ray"], "--engine local"))
    for opts, says in refused:
        bad = batch(str(inputs), "-o", str(tmp_path / "bad"), *SMALL, *opts)
        _, err = bad.communicate(timeout=60)
        assert bad.returncode == 2 and says in err, err


def test_two_jobs_asked_by_a_program_read_from_stdin_run_one_at_a_time(inputs, tmp_path):
    """``spawn`` starts a job's process by running the caller's main script again, which ``python -`` does not have:
    the inputs are then taken one at a time instead of each failing as "its process died"."""
    program = (
        "from deepcrashtest.pipeline.batch import run_batch\n"
        "from deepcrashtest.search.run import SearchConfig\n"
        "import json, sys\n"
        "cfg = SearchConfig(starts=2, noise_variants=2, method='random', video=False)\n"
        f"print(json.dumps(run_batch({str(inputs)!r}, {str(tmp_path / 'out')!r}, cfg, jobs=2)))\n"
    )
    proc = subprocess.run([sys.executable, "-"], input=program, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    res = json.loads(proc.stdout.strip().splitlines()[-1])
    assert res["done"] == len(CRASHES) and res["failed"] == 1 and "e_broken" in res["errors"]
