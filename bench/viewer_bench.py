"""Viewer and report timings on KITTI 0008 (27 agents, 390 frames) and the bundled 1280x720 clip.

Prints: /api/edit round trip (validate + edit + validate, JSON both ways), /api/frame during playback
(25 fps steps) and after random seeks, and the time to build report.html with a contact sheet.
Timings on a shared machine are inflated by whatever else runs there.
"""

from __future__ import annotations

import json
import shutil
import statistics
import sys
import tempfile
import time
from pathlib import Path

from fastapi.testclient import TestClient

ROOT = Path(__file__).resolve().parents[1]
KITTI = ROOT.parent / "shared" / "data" / "kitti_tracking"
VIDEO = ROOT / "examples" / "highway_sample.mp4"


def _ms(samples: list[float]) -> str:
    return f"median {statistics.median(samples) * 1000:.1f} ms, max {max(samples) * 1000:.1f} ms (n={len(samples)})"


def main() -> int:
    from deepcrashtest.datasets.kitti.scenario import scenario_from_kitti
    from deepcrashtest.viz.report import build_report
    from deepcrashtest.viz.server import create_app

    if not KITTI.exists():
        print(f"skipped: {KITTI} not found")
        return 0
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        sc = scenario_from_kitti(KITTI, 8)
        sc.save(folder / "scenario.json")
        shutil.copyfile(VIDEO, folder / "annotated.mp4")
        client = TestClient(create_app(folder / "scenario.json"), base_url="http://127.0.0.1")
        body = sc.model_dump(mode="json")
        times = []
        for i in range(20):
            edit = {"kind": "shift", "vehicle_id": 9, "d_lon": 0.0, "d_lat": 0.01 * (i + 1)}
            t0 = time.perf_counter()
            r = client.post(
                "/api/edit",
                content=json.dumps({"scenario": body, "edit": edit}),
                headers={"Content-Type": "application/json"},
            )
            times.append(time.perf_counter() - t0)
            assert r.status_code == 200, r.text
        size_kb = len(json.dumps(body)) / 1024
        print(f"/api/edit on KITTI 0008 ({size_kb:.0f} KiB scenario): {_ms(times)}")
        play = []
        for k in range(50):
            t0 = time.perf_counter()
            assert client.get("/api/frame", params={"t": 2.0 + k / 25}).status_code == 200
            play.append(time.perf_counter() - t0)
        print(f"/api/frame playback (25 fps steps, 960 px JPEG): {_ms(play)}")
        seek = []
        for t in (6.1, 0.7, 4.3, 7.5, 1.9, 5.2, 3.3, 0.1):
            t0 = time.perf_counter()
            assert client.get("/api/frame", params={"t": t}).status_code == 200
            seek.append(time.perf_counter() - t0)
        print(f"/api/frame random seek: {_ms(seek)}")
        t0 = time.perf_counter()
        res = build_report(folder / "scenario.json", folder / "report.html")
        print(
            f"report.html with contact sheet: {time.perf_counter() - t0:.2f} s, {res['bytes'] / 1e6:.2f} MB, "
            f"{len(res['sections'])} sections"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
