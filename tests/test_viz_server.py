"""The viewer's HTTP API (FastAPI TestClient): edits, saving, video frames and every kind of bad request."""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest
from fastapi.testclient import TestClient

from deepcrashtest.scenario import Scenario
from deepcrashtest.viz.server import create_app

ROOT = Path(__file__).resolve().parents[1]
SAMPLE_VIDEO = ROOT / "examples" / "highway_sample.mp4"
BASE = "http://127.0.0.1"


@pytest.fixture()
def folder(tmp_path, kitti8_raw) -> Path:
    d = tmp_path / "case"
    d.mkdir()
    kitti8_raw.save(d / "scenario.json")
    return d


@pytest.fixture()
def client(folder) -> TestClient:
    return TestClient(create_app(folder / "scenario.json"), base_url=BASE)


def _post(client: TestClient, path: str, body: object):
    return client.post(path, content=json.dumps(body), headers={"Content-Type": "application/json"})


def test_page_and_scenario_are_served(client, folder):
    page = client.get("/")
    assert page.status_code == 200 and "<canvas" in page.text and "/static/viewer.js" in page.text
    assert "http" not in page.text.replace("http-equiv", "")  # nothing from a CDN
    js = client.get("/static/viewer.js")
    assert js.status_code == 200 and js.headers["content-type"].startswith("text/javascript")
    data = client.get("/api/scenario").json()
    assert Scenario.from_dict(data["scenario"]) == Scenario.load(folder / "scenario.json")
    assert data["file"] == "scenario.json"
    assert data["video"] is None and "no annotated.mp4" in data["video_note"]
    assert len(data["road"]["boundaries"]) == data["scenario"]["road"]["lane_count"] + 1
    n = data["scenario"]["road"]["oncoming_lane_count"]
    assert len(data["road"]["oncoming"]) == (n + 1 if n else 0)
    frame = client.get("/api/frame", params={"t": 1.0})
    assert frame.status_code == 404 and "no annotated.mp4" in frame.json()["error"]


@pytest.mark.parametrize("path", ["/static/../server.py", "/static/..%2Fserver.py", "/static/index.htm", "/etc/passwd"])
def test_static_paths_outside_the_whitelist_are_404(client, path):
    r = client.get(path)
    assert r.status_code == 404 and "error" in r.json()


def test_edit_returns_the_edited_scenario(client, kitti8_raw):
    sc = kitti8_raw
    x0 = sc.vehicle(9).trajectory.x[50]
    edit = {"kind": "move_waypoint", "vehicle_id": 9, "index": 50, "x": x0 + 1.0, "y": 0.0, "falloff_s": 0.5}
    r = _post(client, "/api/edit", {"scenario": sc.model_dump(mode="json"), "edit": edit})
    assert r.status_code == 200, r.text
    new = Scenario.from_dict(r.json()["scenario"])
    assert new.vehicle(9).trajectory.x[50] == pytest.approx(x0 + 1.0)
    assert new.vehicle(9).trajectory.y[50] == 0.0
    assert r.json()["description"] == new.provenance.history[-1]


@pytest.mark.parametrize(
    ("body", "status", "message"),
    [
        (b"{not json", 400, "invalid JSON"),
        (b'{"scenario": NaN}', 400, "NaN"),
        (b"[1, 2]", 400, "JSON object"),
        (b'{"edit": {}}', 422, "no 'scenario'"),
    ],
)
def test_malformed_bodies_are_4xx_with_an_error(client, body, status, message):
    r = client.post("/api/edit", content=body, headers={"Content-Type": "application/json"})
    assert r.status_code == status and message in r.json()["error"]


def test_nan_coordinates_are_refused(client, kitti8_raw):
    text = json.dumps({"scenario": kitti8_raw.model_dump(mode="json"), "edit": {"kind": "shift", "vehicle_id": 9}})
    text = text.replace('"x": [', '"x": [NaN, ', 1)  # a raw NaN literal in a coordinate list
    r = client.post("/api/edit", content=text, headers={"Content-Type": "application/json"})
    assert r.status_code == 400 and "NaN" in r.json()["error"]
    data = kitti8_raw.model_dump(mode="json")
    data["agents"][0]["trajectory"]["x"][0] = None  # what JSON.stringify makes of NaN
    r = _post(client, "/api/edit", {"scenario": data, "edit": {"kind": "shift", "vehicle_id": 9}})
    assert r.status_code == 422 and "agents.0.trajectory.x.0" in r.json()["error"]
    r = client.post(
        "/api/edit",
        content=json.dumps(
            {"scenario": kitti8_raw.model_dump(mode="json"), "edit": {"kind": "shift", "vehicle_id": 9}}
        ).replace('"vehicle_id": 9', '"vehicle_id": 9, "d_lat": Infinity'),
        headers={"Content-Type": "application/json"},
    )
    assert r.status_code == 400 and "Infinity" in r.json()["error"]


def test_unknown_vehicle_and_invalid_scenario_are_422(client, kitti8_raw):
    data = kitti8_raw.model_dump(mode="json")
    r = _post(client, "/api/edit", {"scenario": data, "edit": {"kind": "shift", "vehicle_id": 4242, "d_lat": 1}})
    assert r.status_code == 422 and "4242 is not a vehicle" in r.json()["error"]
    data["ego"]["trajectory"]["t"][3] = data["ego"]["trajectory"]["t"][2]
    r = _post(client, "/api/edit", {"scenario": data, "edit": {"kind": "shift", "vehicle_id": 9}})
    assert r.status_code == 422 and "ego.trajectory" in r.json()["error"] and "increase" in r.json()["error"]


def test_non_json_content_type_and_foreign_host_are_refused(client, kitti8_raw):
    body = json.dumps({"scenario": kitti8_raw.model_dump(mode="json"), "filename": "x.json"})
    r = client.post("/api/save", content=body, headers={"Content-Type": "text/plain"})  # a cross-site form post
    assert r.status_code == 415
    r = TestClient(client.app, base_url="http://evil.example").get("/api/scenario")  # DNS rebinding
    assert r.status_code == 400


def test_save_as_writes_a_new_file_and_never_overwrites_silently(client, folder, kitti8_raw):
    original = (folder / "scenario.json").read_bytes()
    edited = _post(
        client,
        "/api/edit",
        {"scenario": kitti8_raw.model_dump(mode="json"), "edit": {"kind": "shift", "vehicle_id": 9, "d_lat": 0.5}},
    ).json()["scenario"]
    r = _post(client, "/api/save", {"scenario": edited, "filename": "fixed.json"})
    assert r.status_code == 200, r.text
    saved = Scenario.load(folder / "fixed.json")
    assert saved.provenance.history[0].startswith("shift vehicle=9")
    assert "saved by deepcrashtest view as fixed.json" in saved.provenance.history[-1]
    assert [p.name for p in folder.iterdir() if p.name.startswith(".")] == []  # no temp file left
    r = _post(client, "/api/save", {"scenario": edited, "filename": "fixed.json"})
    assert r.status_code == 409 and "already exists" in r.json()["error"]
    r = _post(client, "/api/save", {"scenario": edited, "filename": "scenario.json"})
    assert r.status_code == 409
    assert (folder / "scenario.json").read_bytes() == original
    r = _post(client, "/api/save", {"scenario": edited, "filename": "fixed.json", "overwrite": True})
    assert r.status_code == 200
    r = _post(client, "/api/save", {"scenario": edited, "filename": "fixed.json", "overwrite": "yes"})
    assert r.status_code == 400


@pytest.mark.parametrize(
    "name",
    ["../escape.json", "/tmp/escape.json", "sub/escape.json", "..", ".hidden.json", "notes.txt", "", 7, "a\\b.json"],
)
def test_save_rejects_paths_outside_the_folder(client, folder, kitti8_raw, name):
    r = _post(client, "/api/save", {"scenario": kitti8_raw.model_dump(mode="json"), "filename": name})
    assert r.status_code == 400, r.text
    assert "error" in r.json()
    assert sorted(p.name for p in folder.iterdir()) == ["scenario.json"]
    assert not (folder.parent / "escape.json").exists()


def test_save_refuses_a_symlink_out_of_the_folder(client, folder, kitti8_raw, tmp_path):
    outside = tmp_path / "outside.json"
    outside.write_text("keep me")
    os.symlink(outside, folder / "link.json")
    r = _post(client, "/api/save", {"scenario": kitti8_raw.model_dump(mode="json"), "filename": "link.json"})
    assert r.status_code == 400 and "symlink" in r.json()["error"]
    r = _post(
        client,
        "/api/save",
        {"scenario": kitti8_raw.model_dump(mode="json"), "filename": "link.json", "overwrite": True},
    )
    assert r.status_code == 400
    assert outside.read_text() == "keep me"


def test_simulate_runs_the_simulator(client, kitti8_raw):
    r = _post(client, "/api/simulate", {"scenario": kitti8_raw.model_dump(mode="json")})
    assert r.status_code == 200, r.text
    out = r.json()
    assert set(out["metrics"]) >= {"collided", "collision_time", "delta_v_ego", "min_distance"}
    assert len(out["times"]) == len(out["states"]) == len(out["present"]) <= 801
    assert out["vehicle_ids"][0] == 0


def decoded_frames(path: Path) -> list[np.ndarray]:
    """Every frame of a video, in order, decoded straight through with PyAV (no seeking): the reference."""
    import av

    with av.open(str(path)) as c:
        return [f.to_ndarray(format="rgb24") for f in c.decode(video=0)]


def frame_error(got: np.ndarray, ref: np.ndarray) -> float:
    """Mean absolute difference (0-255) between a shown frame and a reference frame scaled to its size."""
    return float(np.abs(got.astype(float) - cv2.resize(ref, got.shape[1::-1], interpolation=cv2.INTER_AREA)).mean())


def with_video_offset(sc: Scenario, offset_s: float) -> Scenario:
    """The scenario as if extracted from the sample video (25 fps, 200 frames) with ``offset_s`` of lead-in."""
    src = sc.source.model_copy(update={"fps": 25.0, "frame_count": 200, "width": 1280, "height": 720})
    return sc.evolve(source=src.model_copy(update={"time_offset_s": offset_s}))


def test_frames_of_the_annotated_video_follow_the_scenario_time(folder, kitti8_raw):
    sc = with_video_offset(kitti8_raw, 1.5)  # scenario t = video t + 1.5 s
    sc.save(folder / "scenario.json", force=True)
    shutil.copyfile(SAMPLE_VIDEO, folder / "annotated.mp4")
    client = TestClient(create_app(folder / "scenario.json"), base_url=BASE)
    data = client.get("/api/scenario").json()
    assert data["video"]["fps"] == 25.0 and data["video"]["width"] == 1280
    assert data["time"]["offset_s"] == 1.5 and data["time"]["frame_count"] == 200
    assert data["time"]["video_start_s"] == 1.5 and data["time"]["video_end_s"] == pytest.approx(9.5)
    ref = decoded_frames(SAMPLE_VIDEO)
    for t in (1.5, 3.5, 3.54, 7.0, 2.5, 9.45):
        r = client.get("/api/frame", params={"t": t})
        assert r.status_code == 200 and r.headers["content-type"] == "image/jpeg"
        k = sc.video_frame(t)
        assert k == int(np.floor((t - 1.5) * 25 + 1e-6)) and r.headers["x-video-frame"] == str(k)
        got = cv2.cvtColor(cv2.imdecode(np.frombuffer(r.content, np.uint8), cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)
        near = [j for j in (k - 25, k - 1, k, k + 1, k + 25) if 0 <= j < len(ref)]
        small = cv2.resize  # the reference frames scaled to the served size
        errs = {
            j: np.abs(got.astype(float) - small(ref[j], got.shape[1::-1], interpolation=cv2.INTER_AREA)).mean()
            for j in near
        }
        assert errs[k] < 3.0, (t, errs)  # JPEG error only
        assert errs[k] == min(errs.values()), (t, k, errs)  # and not the next, the previous or one a second away
    by_index = client.get("/api/frame", params={"frame": 50})
    assert by_index.status_code == 200 and by_index.headers["x-video-frame"] == "50"
    # outside the video: a state, never a frozen first or last frame
    for t, state in ((0.0, "before"), (1.49, "before"), (9.5, "after"), (12.0, "after")):
        r = client.get("/api/frame", params={"t": t})
        assert r.status_code == 404 and r.json()["state"] == state, (t, r.text)
    assert client.get("/api/frame", params={"frame": 200}).json()["state"] == "after"
    r = client.get("/api/frame", params={"t": "nan"})
    assert r.status_code == 422
    r = client.get("/api/frame", params={"t": "soon"})
    assert r.status_code == 422 and "error" in r.json()


def test_a_video_symlinked_from_outside_is_not_served(folder, tmp_path):
    outside = tmp_path / "elsewhere.mp4"
    shutil.copyfile(SAMPLE_VIDEO, outside)
    os.symlink(outside, folder / "annotated.mp4")
    client = TestClient(create_app(folder / "scenario.json"), base_url=BASE)
    data = client.get("/api/scenario").json()
    assert data["video"] is None and "symlink" in data["video_note"]
    assert client.get("/api/frame", params={"t": 1}).status_code == 404


def test_view_command_serves_on_loopback(folder):
    import socket
    import subprocess
    import sys
    import time

    import httpx

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    cmd = [sys.executable, "-m", "deepcrashtest.cli", "view", str(folder / "scenario.json"), "--port", str(port)]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 60
        while True:
            try:
                r = httpx.get(f"http://127.0.0.1:{port}/api/scenario", timeout=2)
                break
            except httpx.TransportError:
                assert proc.poll() is None, proc.communicate()
                assert time.monotonic() < deadline, "viewer did not start"
                time.sleep(0.2)
        assert r.status_code == 200 and r.json()["file"] == "scenario.json"
    finally:
        proc.terminate()
        _, err = proc.communicate(timeout=20)
    assert f"viewer on http://127.0.0.1:{port}/" in err


def test_projected_boxes_over_the_video_match_kittis_labelled_boxes(folder, kitti8_raw, kitti_root):
    """/api/project: each road user's 3D box in each video frame (scenario time by Scenario.frame_time) lands on
    KITTI's own 2D label of that track in that frame."""
    from deepcrashtest.datasets.kitti.files import read_labels
    from deepcrashtest.perception.boxes import iou_matrix

    shutil.copyfile(SAMPLE_VIDEO, folder / "annotated.mp4")  # only the frame count matters here: 200 of 390
    client = TestClient(create_app(folder / "scenario.json"), base_url=BASE)
    lab = read_labels(kitti_root / "label_02" / "0008.txt")
    lab = lab[lab["type"].isin(["Car", "Van"]) & (lab["occluded"] == 0) & (lab["truncated"] == 0)]

    def label_ious(sc: Scenario) -> list[float]:
        out = _post(client, "/api/project", {"scenario": sc.model_dump(mode="json")}).json()
        assert out["source"] == "scenario trajectories" and (out["width"], out["height"]) == (1242, 375)
        frames = {int(f): boxes for f, boxes in out["frames"].items()}
        assert frames and max(frames) < 200
        ious = []
        for row in lab[lab["frame"] < 200].itertuples():
            box = next((b for vid, b in frames.get(row.frame, []) if vid == row.track_id + 1), None)
            if box is not None:
                seg = np.asarray(box, float)
                got = np.array([[seg[:, 0::2].min(), seg[:, 1::2].min(), seg[:, 0::2].max(), seg[:, 1::2].max()]])
                ious.append(float(iou_matrix(got, np.array([[row.x1, row.y1, row.x2, row.y2]]))[0, 0]))
        return ious

    ious = label_ious(kitti8_raw)
    # ORB-SLAM-placed labels over the scenario's flat road sit ~9 px low (see test_fidelity): IoU ~0.55-0.65
    assert len(ious) > 100 and np.median(ious) > 0.55, (len(ious), np.median(ious))
    # 0.3 s (3 frames) off in the time mapping must show
    late = kitti8_raw.evolve(source=kitti8_raw.source.model_copy(update={"time_offset_s": 0.3}))
    assert np.median(label_ious(late)) < np.median(ious) - 0.03
    sim = {"times": [0.0, 1.0], "vehicle_ids": [0], "states": [[[0, 0, 0, 1]], [[10, 0, 0, 1]]]}
    only_ego = _post(client, "/api/project", {"scenario": kitti8_raw.model_dump(mode="json"), "sim": sim}).json()
    assert only_ego["source"] == "simulation" and only_ego["frames"] == {}  # no simulated agent: nothing drawn
    bad = _post(client, "/api/project", {"scenario": kitti8_raw.model_dump(mode="json"), "sim": {"times": 1}})
    assert bad.status_code == 422
