"""World tracks (a Scenario's agents) -> KITTI tracking result files (``NNNN.txt``, label_02 layout).

Each agent sample in a video frame becomes one line: ``frame track_id type truncated occluded alpha
x1 y1 x2 y2 h w l x y z ry score`` with the 3D box in that frame's rectified camera-2 frame (bottom
centre on the road, ``camera.height_m`` below the camera; metres, radians) and its 2D box the
projection of the 3D box with ``P2`` (pixels). The world frame is the one of
:mod:`deepcrashtest.datasets.kitti.world` (ego centre at frame 0), so these files score with any KITTI
tracking evaluation (TrackEval, ``deepcrashtest evaluate kitti --tracks``).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from deepcrashtest.datasets.kitti.boxes import project_boxes
from deepcrashtest.datasets.kitti.files import KITTI_IMAGE_SIZE, LABEL_COLUMNS
from deepcrashtest.datasets.kitti.world import KittiWorld
from deepcrashtest.fileio import atomic_path
from deepcrashtest.geometry.frames import camera_points_to_world
from deepcrashtest.scenario import Scenario

#: Scenario category -> KITTI type.
KITTI_TYPES = {
    "car": "Car", "van": "Van", "truck": "Truck", "bus": "Truck",
    "motorcycle": "Cyclist", "bicycle": "Cyclist", "pedestrian": "Pedestrian",
}  # fmt: skip
RESULT_COLUMNS = [*LABEL_COLUMNS, "score"]


def scenario_result_table(
    scenario: Scenario,
    world: KittiWorld,
    P2: np.ndarray,
    observed_only: bool = True,
    image_size: tuple[int, int] = KITTI_IMAGE_SIZE,
) -> pd.DataFrame:
    """The agents of ``scenario`` as KITTI result rows (columns :data:`RESULT_COLUMNS`).

    ``world``: the sequence's poses; ``observed_only``: only samples seen in the video (else every
    sample inside the video's frames)."""
    parts = []
    cam_z = np.array([camera_points_to_world(T, np.zeros((1, 3)))[0, 2] for T in world.poses])
    for a in scenario.agents:
        arr = a.trajectory.arrays()
        frames = np.floor(scenario.video_time(arr["t"]) * scenario.source.fps + 1e-6).astype(int)
        keep = (frames >= 0) & (frames < world.n_frames)
        if observed_only and a.trajectory.observed is not None:
            keep &= np.asarray(a.trajectory.observed, bool)
        if not keep.any():
            continue
        f = frames[keep]
        n = len(f)
        parts.append(
            pd.DataFrame(
                {
                    "frame": f,
                    "track_id": a.id,
                    "type": KITTI_TYPES[a.category],
                    "wx": arr["x"][keep],
                    "wy": arr["y"][keep],
                    "wz": cam_z[f] - scenario.camera.height_m,
                    "yaw": arr["yaw"][keep],
                    "h": np.full(n, a.height),
                    "w": np.full(n, a.width),
                    "l": np.full(n, a.length),
                    "score": np.full(n, a.confidence),
                }
            )  # fmt: skip
        )
    if not parts:
        return pd.DataFrame({c: pd.Series(dtype=float) for c in RESULT_COLUMNS})
    t = pd.concat(parts, ignore_index=True).sort_values(["frame", "track_id"], ignore_index=True)
    xyz = np.zeros((len(t), 3))
    ry = np.zeros(len(t))
    fr = t["frame"].to_numpy()
    world_xyz = t[["wx", "wy", "wz"]].to_numpy(float)
    lwh = t[["l", "w", "h"]].to_numpy(float)
    for f in np.unique(fr):
        idx = np.nonzero(fr == f)[0]
        xyz[idx] = world.world_to_camera(int(f), world_xyz[idx])
        ry[idx] = world.yaw_to_camera(int(f), t["yaw"].to_numpy(float)[idx])
    box = project_boxes(P2, xyz, lwh, ry, image_size)
    t["x"], t["y"], t["z"], t["ry"] = xyz[:, 0], xyz[:, 1], xyz[:, 2], ry
    t["x1"], t["y1"], t["x2"], t["y2"] = box.T
    t["alpha"] = ry - np.arctan2(xyz[:, 0], xyz[:, 2])
    t["truncated"], t["occluded"] = 0.0, 0
    inside = np.isfinite(box).all(axis=1)
    t.loc[~inside, ["x1", "y1", "x2", "y2"]] = -1.0
    return t[RESULT_COLUMNS]


def write_results(table: pd.DataFrame, path: str | Path, force: bool = False) -> Path:
    """Write result rows (:data:`RESULT_COLUMNS`) as a KITTI tracking result file, atomically."""
    lines = [
        f"{r.frame:.0f} {r.track_id:.0f} {r.type} {r.truncated:g} {r.occluded:.0f} {r.alpha:.4f} "
        f"{r.x1:.2f} {r.y1:.2f} {r.x2:.2f} {r.y2:.2f} {r.h:.4f} {r.w:.4f} {r.l:.4f} "
        f"{r.x:.4f} {r.y:.4f} {r.z:.4f} {r.ry:.4f} {r.score:.4f}"
        for r in table.itertuples(index=False)
    ]
    with atomic_path(Path(path), force=force) as tmp:
        Path(tmp).write_text("".join(line + "\n" for line in lines))
    return Path(path)
