"""report.html: section builders on real KITTI 0008 data and the bundled real video; the report command."""

from __future__ import annotations

import base64
import json
import re
import shutil
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pandas as pd
import pytest

from deepcrashtest.errors import UserError
from deepcrashtest.scenario import LaneTimeline
from deepcrashtest.viz.report import (
    contact_sheet_section,
    distance_to_ego,
    lane_offset_section,
    render_report,
    scenario_sections,
    search_section,
    simulation_section,
    write_report,
)

SAMPLE_VIDEO = Path(__file__).resolve().parents[1] / "examples" / "highway_sample.mp4"


def _pngs(html_text: str) -> list[np.ndarray]:
    """The embedded pictures (PNG plots; the contact sheet is a JPEG)."""
    out = []
    for b64 in re.findall(r'src="data:image/(?:png|jpeg);base64,([A-Za-z0-9+/=]+)"', html_text):
        img = cv2.imdecode(np.frombuffer(base64.b64decode(b64), np.uint8), cv2.IMREAD_COLOR)
        assert img is not None
        out.append(img)
    return out


def _search_table() -> pd.DataFrame:
    """A search-shaped table: 5 x 5 start offsets, collided where the robustness is negative."""
    dx, dy = np.meshgrid(np.linspace(-4, 4, 5), np.linspace(-1, 1, 5))
    rob = 0.5 * dx.ravel() - 0.2
    return pd.DataFrame({"dx": dx.ravel(), "dy": dy.ravel(), "robustness": rob, "collided": rob < 0})


def test_report_of_kitti_0008_is_one_self_contained_file(tmp_path, kitti8_raw):
    sections = scenario_sections(
        kitti8_raw,
        sim_metrics={"collided": False, "collision_time": None, "delta_v_ego": float("nan"), "min_distance": 1.82},
        search=_search_table(),
    )
    path = write_report(tmp_path / "report.html", *sections, None, title="KITTI 0008")
    text = path.read_text(encoding="utf-8")
    titles = [s.title for s in sections]
    assert titles == [
        "Scenario",
        "Warnings",
        "Source video",
        "Camera and calibration",
        "Bird's-eye view",
        "Speed and distance over time",
        "Simulation outcome",
        "Search: start positions",
    ]
    for t in titles:
        assert f"<h2>{t.replace(chr(39), '&#x27;')}</h2>" in text
    assert not re.search(r'(src|href)="(?!data:|#)', text)  # nothing loaded from elsewhere
    images = _pngs(text)
    assert len(images) == 3 and all(im.shape[0] > 200 and im.shape[1] > 400 for im in images)
    assert "721.5" in text  # KITTI fx from calib
    assert "kitti_calib" in text
    assert "no collision" in text
    with pytest.raises(UserError, match="already exists"):
        write_report(path, *sections)


def test_closest_approach_matches_the_trajectories(kitti8_raw):
    agent = kitti8_raw.vehicle(9)
    t, d = distance_to_ego(kitti8_raw, agent)
    e, a = kitti8_raw.ego.trajectory, agent.trajectory
    # KITTI agents are sampled at the ego's frame times: distances are plain differences
    i = 37
    assert t[i] == a.t[i]
    k = e.t.index(a.t[i])
    assert d[i] == pytest.approx(np.hypot(a.x[i] - e.x[k], a.y[i] - e.y[k]))


def test_contact_sheet_from_the_real_video():
    sec = contact_sheet_section(SAMPLE_VIDEO, frames=6, columns=3, thumb_width=200)
    (sheet,) = _pngs(sec.body)
    assert sheet.shape[1] >= 3 * 180 and sheet.shape[0] >= 2 * 100
    assert "1280 x 720 px, 25 fps, 8.00 s" in sec.body
    assert sheet.std() > 20  # real picture content, not a blank canvas


def test_search_section_counts_safe_variants():
    df = _search_table()
    sec = search_section(df)
    n_safe = int((~df["collided"]).sum())
    assert f"<th>safe variants</th><td>{n_safe}</td>" in sec.body
    assert f"<th>collided variants</th><td>{25 - n_safe}</td>" in sec.body
    assert len(_pngs(sec.body)) == 1
    # the search's own results.csv names the offsets d_lon / d_lat and has a safe column
    csv_like = df.rename(columns={"dx": "d_lon", "dy": "d_lat"}).assign(safe=lambda x: ~x["collided"])
    assert f"<th>safe variants</th><td>{n_safe}</td>" in search_section(csv_like).body
    with pytest.raises(UserError, match="robustness"):
        search_section(df.drop(columns=["robustness"]))


def test_lane_offset_only_with_a_lane_timeline(kitti8_raw):
    assert lane_offset_section(kitti8_raw) is None
    t = kitti8_raw.ego.trajectory.t
    offs = (np.asarray(kitti8_raw.ego.trajectory.y) - np.asarray(kitti8_raw.ego.trajectory.y).mean()).tolist()
    lanes = [0 if o < 0 else 1 for o in offs]
    timeline = LaneTimeline(t=t, lane_index=lanes, lateral_offset=offs)
    road = kitti8_raw.road.model_copy(update={"lane_timeline": timeline})
    sec = lane_offset_section(kitti8_raw.model_copy(update={"road": road}))
    assert sec is not None
    changes = int(np.count_nonzero(np.diff(lanes)))
    assert f"<p>{changes} lane change(s)." in sec.body


def test_simulation_section_takes_a_result_object_and_escapes():
    class Result:
        metrics = {"collided": True, "collision_time": 2.5, "note": "<script>x</script>"}

    sec = simulation_section(Result())
    assert "collision time (s)</th><td>2.5</td>" in sec.body
    assert "<script>" not in sec.body and "&lt;script&gt;" in sec.body
    assert render_report([sec]).count("<section") == 1


def _cli(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "deepcrashtest.cli", *args], capture_output=True, text=True, timeout=300
    )


def test_report_command_uses_the_files_beside_the_scenario(tmp_path, kitti8_raw):
    folder = tmp_path / "case"
    folder.mkdir()
    sc = kitti8_raw.save(folder / "scenario.json")
    shutil.copyfile(SAMPLE_VIDEO, folder / "annotated.mp4")
    (folder / "simulation.json").write_text(json.dumps({"metrics": {"collided": True, "collision_time": 1.25}}))
    _search_table().to_csv(folder / "results.csv", index=False)
    out = tmp_path / "report.html"
    proc = _cli("report", str(sc), "-o", str(out), "--json")
    assert proc.returncode == 0, proc.stderr
    res = json.loads(proc.stdout)
    assert res["sections"][4] == "Annotated frames" and "Simulation outcome" in res["sections"]
    assert "Search: start positions" in res["sections"]
    assert res["bytes"] == out.stat().st_size
    assert len(_pngs(out.read_text())) == 4  # contact sheet, bird's-eye, motion, search
    again = _cli("report", str(sc), "-o", str(out))
    assert again.returncode == 2 and "already exists" in again.stderr and len(again.stderr.splitlines()) == 1
    assert _cli("report", str(sc), "-o", str(out), "--force").returncode == 0
    missing = _cli("report", str(sc), "-o", str(tmp_path / "r2.html"), "--video", str(tmp_path / "nope.mp4"))
    assert missing.returncode == 2 and "no such video" in missing.stderr


def test_view_command_refuses_bad_input(tmp_path):
    proc = _cli("view", str(tmp_path / "missing.json"))
    assert proc.returncode == 2 and "no such scenario file" in proc.stderr
    proc = _cli("view", str(tmp_path / "missing.json"), "--port", "70000")
    assert proc.returncode == 2 and "--port" in proc.stderr
