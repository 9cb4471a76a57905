"""AB3DMOT detections and oxts packets: the readers on the real files, the Mercator pose conversion
against independent geodesy."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from tests.conftest import DATA, need

from deepcrashtest.datasets.kitti.files import (
    EARTH_RADIUS_M,
    KittiSequence,
    latlon_to_mercator,
    mercator_scale,
    mercator_to_latlon,
    oxts_to_poses,
    read_ab3dmot_detections,
    read_labels,
    read_oxts,
)
from deepcrashtest.errors import UserError

OXTS_DIR = DATA / "kitti_raw_drive0005_frame0" / "2011_09_26" / "2011_09_26_drive_0005_sync" / "oxts" / "data"


def test_pointrcnn_detections(kitti_root):
    path = need(KittiSequence(kitti_root, 8).detections_pointrcnn)
    det = read_ab3dmot_detections(path)
    raw = pd.read_csv(path, header=None)
    assert len(det) == len(raw) and det.shape[1] == 15
    assert (det["type_id"] == 2).all()  # Car
    assert det["frame"].min() >= 0 and det["frame"].max() < 390
    assert (det[["h", "w", "l"]] > 0).all().all() and (det["z"] > 0).all()  # in front of the camera
    np.testing.assert_allclose(det["score"], raw[6])


def test_detections_bad_file(tmp_path):
    p = tmp_path / "0000.txt"
    p.write_text("0,2,1,2,3\n")
    with pytest.raises(UserError, match="15 comma-separated columns"):
        read_ab3dmot_detections(p)
    p.write_text("")
    assert len(read_ab3dmot_detections(p)) == 0


def test_tracker_results_with_extra_columns(kitti_root):
    """GT-SORT's results carry 19 columns; as in TrackEval, column 18 is the score."""
    path = need(kitti_root / "trackeval_reference" / "trackers" / "GT-SORT" / "data" / "0003.txt")
    res = read_labels(path)
    assert "score" in res.columns and len(res) == len(path.read_text().splitlines())
    assert len(read_labels(path.with_name("0017.txt"))) == 0  # an empty results file


def test_real_oxts_packet():
    need(OXTS_DIR)
    ox = read_oxts(OXTS_DIR)
    assert len(ox) == 1
    assert ox["lat"].iloc[0] == pytest.approx(49.011212804408)
    assert ox["lon"].iloc[0] == pytest.approx(8.4228850417969)
    assert ox["yaw"].iloc[0] == pytest.approx(-1.2219096732051)
    assert (ox["navstat"].iloc[0], ox["numsats"].iloc[0]) == (4, 10)
    np.testing.assert_allclose(oxts_to_poses(ox)[0], np.eye(4), atol=1e-9)
    # the one-line-per-packet file layout of the tracking benchmark reads the same
    one = read_oxts(next(OXTS_DIR.glob("*.txt")))
    pd.testing.assert_frame_equal(one, ox)


def test_mercator_round_trip_and_scale():
    lat, lon = np.array([49.011212804408, 48.9]), np.array([8.4228850417969, 8.5])
    s = mercator_scale(lat[0])
    back = mercator_to_latlon(*latlon_to_mercator(lat, lon, s), s)
    np.testing.assert_allclose(back, (lat, lon), atol=1e-10)


def test_oxts_poses_against_local_geodesy():
    """A second packet 30 m north and 40 m east of the real one, car turned by 0.3 rad: the relative
    pose must hold that displacement (in the first car's frame) and the turn."""
    ox = read_oxts(need(OXTS_DIR))
    lat0, lon0 = np.deg2rad(ox["lat"].iloc[0]), ox["lon"].iloc[0]
    second = ox.copy()
    second["lat"] = ox["lat"] + np.rad2deg(30.0 / EARTH_RADIUS_M)
    second["lon"] = lon0 + np.rad2deg(40.0 / (EARTH_RADIUS_M * np.cos(lat0)))
    second["yaw"] = ox["yaw"] + 0.3
    poses = oxts_to_poses(pd.concat([ox, second], ignore_index=True))
    R0 = poses[0][:3, :3]
    yaw, pitch, roll = ox[["yaw", "pitch", "roll"]].iloc[0]
    cz, sz = np.cos(yaw), np.sin(yaw)
    cy, sy = np.cos(pitch), np.sin(pitch)
    cx, sx = np.cos(roll), np.sin(roll)
    Rw = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]]) @ np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    Rw = Rw @ np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    expected = Rw.T @ np.array([40.0, 30.0, 0.0])  # east, north, up -> first IMU frame
    np.testing.assert_allclose(poses[1][:3, 3], expected, atol=0.05)  # 5 cm over 50 m
    np.testing.assert_allclose(R0, np.eye(3), atol=1e-12)
    turn = np.arctan2(*(Rw @ poses[1][:3, :3] @ [1, 0, 0])[[1, 0]]) - yaw
    assert turn == pytest.approx(0.3, abs=0.02)


def test_oxts_bad_packet(tmp_path):
    p = tmp_path / "0000000000.txt"
    p.write_text("49.0 8.4 112.0\n")
    with pytest.raises(UserError, match="30 oxts fields"):
        read_oxts(p)
