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
    motion_section,
    overview_section,
    render_report,
    scenario_sections,
    search_section,
    sheet_frames,
    sheet_marks,
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
        "Vehicle plausibility",
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
    assert "no ego collision" in text and "<th>collision in the scenario</th><td>none</td>" in text
    assert "<summary>Parameters (3)</summary>" in text and "<tr><th>poses</th><td>orbslam3</td></tr>" in text
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


def _with_lane_timeline(sc):
    """``sc`` with a lane timeline from its ego's lateral position (two lanes, split at the mean)."""
    t = sc.ego.trajectory.t
    offs = (np.asarray(sc.ego.trajectory.y) - np.asarray(sc.ego.trajectory.y).mean()).tolist()
    timeline = LaneTimeline(t=t, lane_index=[0 if o < 0 else 1 for o in offs], lateral_offset=offs)
    return sc.model_copy(update={"road": sc.road.model_copy(update={"lane_timeline": timeline})})


def test_report_plots_are_drawn_once_and_fit_their_canvas(kitti8_raw, monkeypatch):
    """Each plot is drawn once, at its figure's own size (``savefig`` drew it twice, and its tight bounding box
    measured it once more: ~0.5 s of CPU a report), and its constrained layout keeps every label and the
    legend inside the canvas: ink near each edge, none on it. The bird's-eye view of a long drive keeps the
    tight box: its zoomed panel's frame reaches beyond the overview's axes."""
    from matplotlib.figure import Figure

    from deepcrashtest.viz.report import birdseye_section

    draws: list[Figure] = []
    draw = Figure.draw

    def counted(self: Figure, renderer: object) -> None:
        draws.append(self)
        draw(self, renderer)

    monkeypatch.setattr(Figure, "draw", counted)
    for make in (lambda: motion_section(kitti8_raw), lambda: lane_offset_section(_with_lane_timeline(kitti8_raw))):
        draws.clear()
        section = make()
        assert section is not None
        (png,) = _pngs(section.body)
        (fig,) = draws
        w, h = fig.get_size_inches() * fig.dpi
        assert abs(png.shape[0] - h) < 1 and abs(png.shape[1] - w) < 1, (png.shape, w, h)  # main: 0.2 in more
        ink = (png < 250).any(axis=2)
        rows, cols = np.flatnonzero(ink.any(axis=1)), np.flatnonzero(ink.any(axis=0))
        margins = (rows[0], png.shape[0] - 1 - rows[-1], cols[0], png.shape[1] - 1 - cols[-1])
        assert all(1 <= m <= 12 for m in margins), margins
    draws.clear()
    (png,) = _pngs(birdseye_section(kitti8_raw).body)
    fig = draws[0]
    assert len(fig.axes) == 2 and png.shape[1] > fig.get_size_inches()[0] * fig.dpi  # the zoom frame kept whole


def test_contact_sheet_from_the_real_video():
    sec = contact_sheet_section(SAMPLE_VIDEO, frames=6, columns=3, thumb_width=200)
    (sheet,) = _pngs(sec.body)
    assert sheet.shape[1] >= 3 * 180 and sheet.shape[0] >= 2 * 100
    assert "1280 x 720 px, 25 fps, 8.00 s" in sec.body
    assert sheet.std() > 20  # real picture content, not a blank canvas
    assert sheet_frames(200, 6) == [16, 50, 83, 116, 150, 183]


def test_report_times_follow_the_one_time_mapping(kitti8_raw):
    """Collision, contact sheet marks and closest approaches are in scenario AND video time, by Scenario's mapping."""
    from deepcrashtest.scenario import Collision

    src = kitti8_raw.source.model_copy(update={"time_offset_s": 5.65})
    a, b = kitti8_raw.agents[0].id, kitti8_raw.agents[1].id  # a third-party crash: two agents
    sc = kitti8_raw.evolve(source=src, collision=Collision(time_s=10.21, other_id=a, agent_id=b, source="user"))
    over = overview_section(sc).body
    assert f"agent {a} (car" in over and "given by the user" in over
    assert "scenario t = 10.21 s = video t = 4.56 s (frame 45)" in over  # 10 fps: floor(4.56 * 10) = 45
    assert "scenario t = video t + 5.65 s" in over and "covers scenario t 5.65-44.65 s" in over
    late = sc.evolve(collision=Collision(time_s=50.0, other_id=0, agent_id=b))
    assert "after the video&#x27;s end at 39.00 s" in overview_section(late).body
    marks = sheet_marks(sc, 390, 12)
    assert marks[0] == ("#1", pytest.approx(16 / 10 + 5.65)) and len(marks) == 12
    assert marks[1] == ("#2", pytest.approx(45 / 10 + 5.65))  # the collision's frame 45 replaces frame 48
    motion = motion_section(sc, marks)
    assert "= video t = " in motion.body and len(_pngs(motion.body)) == 1


def test_simulation_section_names_the_ego_collision_and_counts_the_others():
    metrics = {"collided": False, "delta_v_ego": None, "n_collisions": 2}
    collisions = [
        {"time": 1.2, "vehicles": [1, 5], "relative_speed": 2.0, "delta_v": {"1": 0.7, "5": 0.7}},
        {"time": 3.9, "vehicles": [5, 6], "relative_speed": 1.4, "delta_v": {"5": 0.0, "6": 0.0}},
    ]
    body = simulation_section({**metrics, "collisions": collisions}).body
    assert "no ego collision; 2 collision(s) between other road users" in body
    assert body.count("<li>") == 2 and "agent 1 and agent 5 at t = 1.20 s" in body
    hit = {"collided": True, "collision_time": 2.5, "collision_vehicle": 16, "delta_v_ego": None, "n_collisions": 2}
    ego_entry = {"time": 2.5, "vehicles": [0, 16], "relative_speed": 6.4, "delta_v": {"0": 6.39, "16": 5.0}}
    body = simulation_section({**hit, "collisions": [ego_entry, collisions[0]]}).body
    assert "ego collision with agent 16 at t = 2.50 s; 1 collision(s) between other road users" in body
    assert "<th>delta v ego (m/s)</th><td>6.39</td>" in body  # from the ego's collision entry


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
    sc = _with_lane_timeline(kitti8_raw)
    sec = lane_offset_section(sc)
    assert sec is not None
    assert sc.road.lane_timeline is not None
    changes = int(np.count_nonzero(np.diff(sc.road.lane_timeline.lane_index)))
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
    ego_hit = {"time": 1.25, "vehicles": [0, 9], "point": [1.0, 2.0], "relative_speed": 6.4, "delta_v": {"0": 6.39}}
    sim_json = {"metrics": {"collided": True, "collision_time": 1.25, "collision_vehicle": 9}, "collisions": [ego_hit]}
    (folder / "simulation.json").write_text(json.dumps(sim_json))  # the shape of `deepcrashtest simulate --json`
    _search_table().to_csv(folder / "results.csv", index=False)
    out = tmp_path / "report.html"
    proc = _cli("report", str(sc), "-o", str(out), "--json")
    assert proc.returncode == 0, proc.stderr
    res = json.loads(proc.stdout)
    assert res["sections"][4] == "Annotated frames" and "Simulation outcome" in res["sections"]
    assert "Search: start positions" in res["sections"]
    assert res["bytes"] == out.stat().st_size
    text = out.read_text()
    assert len(_pngs(text)) == 4  # contact sheet, bird's-eye, motion, search
    assert "ego collision with agent 9 (car" in text and "<th>delta v ego (m/s)</th><td>6.39</td>" in text
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
