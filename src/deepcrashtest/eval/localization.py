"""Monocular localisation accuracy on the labelled KITTI tracking frames (labelled 2D boxes as input).

For every ``image_02/SSSS/FFFFFF.png`` present, the frame's labelled Car boxes are placed with a
localiser (camera = the sequence's P2 intrinsics, 1.65 m high, level) and compared with the
labels' 3D positions: relative error of the ground distance ``hypot(x, z)`` from the camera to
the car, for cars whose true distance is below ``max_distance_m``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from deepcrashtest.datasets.kitti.files import KITTI_CAMERA_HEIGHT_M, KITTI_IMAGE_SIZE, read_calib, read_labels
from deepcrashtest.errors import UserError
from deepcrashtest.geometry.localize import GroundPlaneLocalizer, Localizer
from deepcrashtest.scenario import Camera


def kitti_localization_errors(
    root: str | Path, localizer: Localizer | None = None, max_distance_m: float = 40.0
) -> dict[str, Any]:
    """Median / 90th-percentile relative distance errors (%), all cars and not-truncated cars."""
    base = Path(root)
    folders = sorted(p for p in (base / "image_02").glob("*") if p.is_dir())
    if not folders:
        raise UserError(f"{base}/image_02: no labelled image folders")
    loc = localizer or GroundPlaneLocalizer()
    rel: list[float] = []
    truncated: list[bool] = []
    for folder in folders:
        labels = read_labels(base / "label_02" / f"{folder.name}.txt")
        K = read_calib(base / "calib" / f"{folder.name}.txt").K
        cam = Camera(fx=K[0, 0], fy=K[1, 1], cx=K[0, 2], cy=K[1, 2], height_m=KITTI_CAMERA_HEIGHT_M)
        for img in sorted(folder.glob("*.png")):
            d = labels[(labels["frame"] == int(img.stem)) & (labels["type"] == "Car")]
            true = np.hypot(d["x"].to_numpy(float), d["z"].to_numpy(float))
            d, true = d[true < max_distance_m], true[true < max_distance_m]
            if not len(d):
                continue
            p = loc.localize(d[["x1", "y1", "x2", "y2"]].to_numpy(float), ["car"] * len(d), cam, KITTI_IMAGE_SIZE)
            rel.extend((np.abs(p.distance - true) / true).tolist())
            truncated.extend((d["truncated"] > 0.3).tolist())
    r = np.array(rel)
    t = np.array(truncated, dtype=bool)

    def stats(x: np.ndarray) -> dict[str, Any]:
        if not x.size:
            return {"cars": 0}
        return {
            "cars": int(x.size),
            "median_pct": round(100 * float(np.median(x)), 2),
            "p90_pct": round(100 * float(np.percentile(x, 90)), 2),
        }

    return {"max_distance_m": max_distance_m, "all": stats(r), "not_truncated": stats(r[~t])}
