"""A raw Scenario from KITTI tracking ground truth: labels placed in the world frame with ego poses.

This gives real trajectories before (and independently of) the perception stages: the camera
pose of every frame (ORB-SLAM3, metric) becomes the ego, and every labelled Car, Van and Truck
becomes an agent whose label position (bottom centre of its 3D box, camera frame) is mapped
into the world frame (origin at the ego centre at frame 0, x forward, y left).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from deepcrashtest.datasets.kitti.files import (
    KITTI_CAMERA_HEIGHT_M,
    KITTI_FPS,
    KITTI_IMAGE_SIZE,
    KittiSequence,
    read_calib,
    read_labels,
    read_poses,
)
from deepcrashtest.errors import UserError
from deepcrashtest.fileio import sha256_file
from deepcrashtest.geometry.frames import camera_forward_yaw, camera_points_to_world, camera_yaw_to_world
from deepcrashtest.scenario import Camera, Provenance, Road, Scenario, Trajectory, Vehicle, VideoSource

#: KITTI label type -> Scenario vehicle category. Other types (Pedestrian, Cyclist, Tram, Misc,
#: DontCare) are not vehicles of the scenario.
KITTI_VEHICLE_TYPES = {"Car": "car", "Van": "van", "Truck": "truck"}
#: With ``road_users=True`` also: a KITTI Cyclist is a bicycle with its rider (one road user).
KITTI_ROAD_USER_TYPES = {**KITTI_VEHICLE_TYPES, "Pedestrian": "pedestrian", "Cyclist": "bicycle"}
#: Camera position ahead of the KITTI car's centre (camera ~0.27 m ahead of the Velodyne, which
#: sits roughly over the middle of the 4.8 m VW Passat), metres.
KITTI_CAMERA_FORWARD_OFFSET_M = 0.3
KITTI_EGO_SIZE = (4.78, 1.82, 1.48)  # VW Passat B6 estate: length, width, height, metres


def kitti_world_transform(poses: np.ndarray, forward_offset_m: float = KITTI_CAMERA_FORWARD_OFFSET_M):
    """Return a function mapping (frame, camera-frame points) -> world xy, and the ego states.

    World origin: the ego centre at frame 0 (the camera ``forward_offset_m`` behind, on the ground).
    Returns ``(to_world, ego_xy, ego_yaw)`` with ego_xy (N, 2) and ego_yaw (N,) radians.
    """
    cam_xy = np.array([camera_points_to_world(T, np.zeros((1, 3)))[0, :2] for T in poses])
    yaw = np.unwrap(np.array([camera_forward_yaw(T) for T in poses]))
    heading = np.column_stack([np.cos(yaw), np.sin(yaw)])
    ego_xy = cam_xy - forward_offset_m * heading
    origin = ego_xy[0].copy()

    def to_world(frame: int, points_cam: np.ndarray) -> np.ndarray:
        return camera_points_to_world(poses[frame], points_cam)[:, :2] - origin

    return to_world, ego_xy - origin, yaw


def _speed(t: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Speed (m/s) from positions by central differences on the (possibly gappy) time axis."""
    if len(t) < 2:
        return np.zeros_like(t)
    vx = np.gradient(x, t)
    vy = np.gradient(y, t)
    return np.hypot(vx, vy)


def scenario_from_kitti(root: str | Path, sequence: int, road_users: bool = False) -> Scenario:
    """Build a raw (``stage="raw"``) Scenario for one KITTI tracking sequence.

    ``road_users``: also the labelled pedestrians and cyclists (default: vehicles only).
    """
    types = KITTI_ROAD_USER_TYPES if road_users else KITTI_VEHICLE_TYPES
    seq = KittiSequence(Path(root), int(sequence)).check()
    labels = read_labels(seq.labels)
    calib = read_calib(seq.calib)
    poses = read_poses(seq.poses)
    n_frames = len(poses)
    if n_frames < 2:
        raise UserError(f"{seq.poses}: needs at least 2 poses, found {n_frames}")
    to_world, ego_xy, ego_yaw = kitti_world_transform(poses)
    t_all = np.arange(n_frames) / KITTI_FPS

    ego = Vehicle(
        id=0,
        category="car",
        length=KITTI_EGO_SIZE[0],
        width=KITTI_EGO_SIZE[1],
        height=KITTI_EGO_SIZE[2],
        first_frame=0,
        last_frame=n_frames - 1,
        trajectory=Trajectory.from_arrays(
            t_all, ego_xy[:, 0], ego_xy[:, 1], ego_yaw, _speed(t_all, ego_xy[:, 0], ego_xy[:, 1])
        ),
    )
    agents = []
    veh = labels[labels["type"].isin(list(types)) & (labels["frame"] < n_frames)]
    for track_id, g in veh.groupby("track_id", sort=True):
        g = g.sort_values("frame")
        frames = g["frame"].to_numpy()
        xy = np.vstack(
            [to_world(int(f), row[None, :]) for f, row in zip(frames, g[["x", "y", "z"]].to_numpy(), strict=True)]
        )
        # the label's location is the bottom centre of the box: already the centre on the ground
        yaw = np.unwrap(
            np.array(
                [camera_yaw_to_world(poses[int(f)], np.array([ry]))[0] for f, ry in zip(frames, g["ry"], strict=True)]
            )
        )
        t = frames / KITTI_FPS
        agents.append(
            Vehicle(
                id=int(track_id) + 1,  # type: ignore[arg-type]  # 0 is the ego
                category=types[str(g["type"].mode().iloc[0])],  # type: ignore[arg-type]
                length=float(g["l"].median()),
                width=float(g["w"].median()),
                height=float(g["h"].median()),
                confidence=1.0,
                first_frame=int(frames[0]),
                last_frame=int(frames[-1]),
                trajectory=Trajectory.from_arrays(
                    t, xy[:, 0], xy[:, 1], yaw, _speed(t, xy[:, 0], xy[:, 1]), observed=np.ones(len(t), bool)
                ),
            )
        )

    road = _road_from_path(ego_xy)
    K = calib.K
    return Scenario(
        name=f"kitti_{seq.name}",
        stage="raw",
        source=VideoSource(
            kind="kitti_labels",
            path=str(seq.labels),
            fps=KITTI_FPS,
            frame_count=n_frames,
            width=KITTI_IMAGE_SIZE[0],
            height=KITTI_IMAGE_SIZE[1],
            sha256=sha256_file(seq.labels),
        ),
        camera=Camera(
            fx=float(K[0, 0]),
            fy=float(K[1, 1]),
            cx=float(K[0, 2]),
            cy=float(K[1, 2]),
            height_m=KITTI_CAMERA_HEIGHT_M,
            pitch_rad=0.0,
            forward_offset_m=KITTI_CAMERA_FORWARD_OFFSET_M,
            intrinsics_source="kitti_calib",
            pitch_source="kitti_calib",
            height_source="kitti_calib",
        ),
        ego=ego,
        agents=agents,
        road=road,
        provenance=Provenance(
            command="scenario from-kitti",
            parameters={"sequence": int(sequence), "poses": "orbslam3", "fps": KITTI_FPS},
        ),
        warnings=["ego poses are ORB-SLAM3 stereo estimates (metric), not GPS/IMU ground truth"],
    )


def _road_from_path(xy: np.ndarray, spacing_m: float = 2.0) -> Road:
    """Centre-line waypoints every ``spacing_m`` metres along a path (stage 2 refines this)."""
    seg = np.hypot(*np.diff(xy, axis=0).T)
    s = np.concatenate([[0.0], np.cumsum(seg)])
    if s[-1] < spacing_m:  # a (nearly) static ego: a short straight road along its heading
        pts = np.array([xy[0], xy[0] + [spacing_m, 0.0]])
    else:
        keep = np.unique(np.searchsorted(s, np.arange(0.0, s[-1], spacing_m)))
        pts = xy[np.append(keep, len(xy) - 1)]
        pts = pts[np.r_[True, np.hypot(*np.diff(pts, axis=0).T) > 1e-6]]
    return Road(centerline_x=pts[:, 0].tolist(), centerline_y=pts[:, 1].tolist(), source="ego_path")


def labels_frame_table(root: str | Path, sequence: int) -> pd.DataFrame:
    """Convenience: the sequence's labels with world x/y columns added (``wx``, ``wy``)."""
    seq = KittiSequence(Path(root), int(sequence)).check()
    labels = read_labels(seq.labels)
    poses = read_poses(seq.poses)
    to_world, _, _ = kitti_world_transform(poses)
    labels = labels[labels["frame"] < len(poses)].copy()
    w = np.full((len(labels), 2), np.nan)
    for i, (f, x, y, z) in enumerate(labels[["frame", "x", "y", "z"]].to_numpy()):
        w[i] = to_world(int(f), np.array([[x, y, z]]))[0]
    labels["wx"], labels["wy"] = w[:, 0], w[:, 1]
    return labels
