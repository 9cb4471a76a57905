"""Candidate (a) of the image-only focal length, measured: epipolar self-calibration of tracked corners.

    PYTHONPATH=src nice -n 10 python bench/focal_epipolar.py [--gap 2] [--max-frames 160]

With the principal point at the image centre (or the calibration's, where known) and square pixels, a
fundamental matrix ``F`` of a frame pair (tracked Shi-Tomasi corners, LK, USAC-MAGSAC) gives the
essential matrix ``E = K^T F K`` for each candidate focal length; a true essential matrix has two
equal singular values (Mendonca-Cipolla), so the cost ``(s1 - s2) / (s1 + s2)`` of each pair is low
at the true focal length. Under a pure translation ``F`` is skew-symmetric and every focal length
fits (``K^T [e]_x K = det(K) [K^-1 e]_x``): the cost only measures the focal length when the camera
rotates (turns, pitch bounce). Printed per clip: the focal length at the minimum of the median cost
over the pairs, the range within 20 % of that minimum's rise from it to the flattest end (a wide
range = degenerate), the median rotation of the pairs at that focal length, and the true focal length
where known. Not used by extract (see the README's self-calibration paragraph for the figures).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import cv2
import numpy as np

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
GRID = np.exp(np.linspace(np.log(250.0), np.log(6000.0), 121))


def _frames(source: Path, max_frames: int) -> list[np.ndarray]:
    """Greyscale frames of an image folder or a video (at most ``max_frames``)."""
    if source.is_dir():
        files = sorted(source.glob("*.png"))[:max_frames]
        return [cv2.imread(str(f), cv2.IMREAD_GRAYSCALE) for f in files]
    cap, out = cv2.VideoCapture(str(source)), []
    while len(out) < max_frames:
        ok, img = cap.read()
        if not ok:
            break
        out.append(cv2.cvtColor(img, cv2.COLOR_BGR2GRAY))
    cap.release()
    return out


def pair_costs(a: np.ndarray, b: np.ndarray, cx: float, cy: float, bottom: int) -> tuple[np.ndarray, float] | None:
    """Cost over :data:`GRID` of one frame pair, and the rotation (deg) recovered at the cost's minimum."""
    mask = np.full(a.shape, 255, np.uint8)
    mask[a.shape[0] - bottom :] = 0
    p0 = cv2.goodFeaturesToTrack(a, 800, 0.01, 8, mask=mask)
    if p0 is None or len(p0) < 30:
        return None
    p1, st, _ = cv2.calcOpticalFlowPyrLK(a, b, p0, None, winSize=(21, 21), maxLevel=3)
    ok = st[:, 0] == 1
    q0, q1 = p0[ok, 0], p1[ok, 0]
    if len(q0) < 30 or np.median(np.linalg.norm(q1 - q0, axis=1)) < 0.5:
        return None
    F, inl = cv2.findFundamentalMat(q0, q1, cv2.USAC_MAGSAC, 0.75, 0.999, 2000)
    if F is None or F.shape != (3, 3) or int(inl.sum()) < 30:
        return None
    cost = np.empty(len(GRID))
    for i, f in enumerate(GRID):
        K = np.array([[f, 0.0, cx], [0.0, f, cy], [0.0, 0.0, 1.0]])
        s = np.linalg.svd(K.T @ F @ K, compute_uv=False)
        cost[i] = (s[0] - s[1]) / (s[0] + s[1])
    f = float(GRID[int(np.argmin(cost))])
    K = np.array([[f, 0.0, cx], [0.0, f, cy], [0.0, 0.0, 1.0]])
    m = inl[:, 0] == 1
    _, R, _, _ = cv2.recoverPose(K.T @ F @ K, q0[m].astype(float), q1[m].astype(float), K)
    return cost, float(np.degrees(np.linalg.norm(cv2.Rodrigues(R)[0])))


def measure(name: str, source: Path, truth: str, gap: int, max_frames: int, cxy: tuple[float, float] | None) -> None:
    frames = _frames(source, max_frames)
    h, w = frames[0].shape
    cx, cy = cxy or (w / 2, h / 2)
    bottom = int(0.12 * h) if source.suffix == ".mp4" else 0  # dashboards and overlays
    costs, rots = [], []
    for k in range(0, len(frames) - gap, gap):
        r = pair_costs(frames[k], frames[k + gap], cx, cy, bottom)
        if r is not None:
            costs.append(r[0])
            rots.append(r[1])
    if not costs:
        print(f"{name:24} no pair measured")
        return
    med = np.median(np.array(costs), axis=0)
    i = int(np.argmin(med))
    rise = max(med[0], med[-1]) - med[i]
    near = GRID[med <= med[i] + 0.2 * rise]
    print(
        f"{name:24} pairs {len(costs):3d}  focal {GRID[i]:6.0f} px  within 20 % of the rise "
        f"{near.min():5.0f}-{near.max():5.0f} px  cost min {med[i]:.3f} / ends {med[0]:.3f} {med[-1]:.3f}  "
        f"median rotation {np.median(rots):.2f} deg  (true {truth})"
    )


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--gap", type=int, default=2, help="frames between the two of a pair")
    ap.add_argument("--max-frames", type=int, default=160)
    args = ap.parse_args()
    odo = DATA / "kitti_odometry"
    clips = [
        ("kitti odometry seq00", odo / "seq00_frames0000-0159" / "image_0", "718.9", (607.19, 185.22)),
        ("kitti odometry seq06", odo / "seq06_frames0000-0050" / "image_0", "707.1", None),
        ("kitti raw highway queue", DATA / "kitti_raw_highway_queue" / "image_02" / "data", "~721", None),
        ("udacity highway", DATA / "dashcam_udacity" / "highway_project_video.mp4", "1154 (chessboard)", None),
        ("ccd_000014", DATA / "crash_ccd" / "ccd_000014.mp4", "~2200-3400 (overlay)", None),
    ]
    for name, src, truth, cxy in clips:
        measure(name, src, truth, args.gap, args.max_frames, cxy)


if __name__ == "__main__":
    main()
