"""Shared fixtures: paths to the real data in ../shared/data and small helpers."""

from __future__ import annotations

from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data"
KITTI_TRACKING = DATA / "kitti_tracking"


def need(path: Path) -> Path:
    """Skip (with the reason) when a piece of the shared real data is absent."""
    if not path.exists():
        pytest.skip(f"real data not found: {path} (see ../shared/data/README.md)")
    return path


@pytest.fixture(scope="session")
def yolo_ok() -> None:
    """Skip (with the reason) when the YOLO26n ONNX model has not been built (``make test`` builds it)."""
    from deepcrashtest.errors import UserError
    from deepcrashtest.perception.models import yolo26n_path

    try:
        yolo26n_path()
    except UserError as exc:
        pytest.skip(f"{exc} (make test builds it)")


@pytest.fixture(scope="session")
def kitti_root() -> Path:
    return need(KITTI_TRACKING)


@pytest.fixture(scope="session")
def kitti8_raw(kitti_root):
    """The raw Scenario of KITTI tracking sequence 0008 (real labels + ORB-SLAM3 poses)."""
    from deepcrashtest.datasets.kitti.scenario import scenario_from_kitti

    return scenario_from_kitti(kitti_root, 8)
