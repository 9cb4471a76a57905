"""Tried and dropped: the focal length from the visible sides of cars seen obliquely (no ego motion needed).

    PYTHONPATH=src nice -n 10 python bench/selfcalib_sides.py [--boxes tracks|labels] [--dims prior|true]
        [--cache /tmp/selfcalib_diag]

A car driving along the road (or parked beside it) is aligned with the camera's axis. Seen straight
ahead its box shows the rear only, ``w / h ~ W / H``; seen at a bearing ``tan a = (u - cx) / f`` its
near side shows too, and the box widens to about ``(W + L tan a) / H`` of its height. How fast the
box's aspect grows with the column measures ``f`` (only the cars' length-to-width ratio sets it; a
common factor on every aspect is fitted away). Exactly: the box's outer bottom corner is back-projected
onto the ground (horizon row and camera height from ``selfcalib.horizon_and_height``), the class-prior
cuboid (length along the axis) placed there and projected; a Tukey fit of ``log(w / h) - log(w_p / h_p)
- log k`` over a grid of focal lengths, one free ``k`` for all boxes (or one per track), boxes whose
inner edge lies 2-30 % of the width off ``cx``, optionally only tracks that keep their lateral offset (``(u - cx) /
(v_b - v_h)`` steady: not crossing or turning). Per training sequence (never 3, 8, 10) the focal error
against ``P2``.

Measured (training sequences with enough side-on boxes): the model is exact on KITTI's label boxes
with each car's own size (they are the projections of the labelled cuboids; the log-aspect residual
stays within 0.02 at the true focal length on 0005 and 0020), but cars at junctions (0001, 0009:
+0.16..+0.43 near the image centre) leave 10 % median error even then (``--boxes labels --dims true``,
11 sequences); with the class prior's size 32 % (``--boxes labels``), and on the PointRCNN tracks 22 %
(12 of 17; 0002 -21 %, 0006 -51 %, 0015 -48 %, 0018 -23 % where it was needed, 1-sigma 12-45 %): not
used (``geometry/selfcalib_moving.py`` measures those from the ego poses).
On a straight highway it works: the whole Udacity ``highway_project_video`` (``extract --no-lanes
--no-geometry``, YOLO26n, 30 tracks; ``--csv out/tracks.csv``) reads 1143 px (1-sigma 13 %, 9 tracks)
against the chessboard's 1154 px (the default 640 px); but the 20 crash clips of
``bench/fidelity_crashes.py`` (5 s each) have too few cars with their side in view: None on every one.
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd

from deepcrashtest.geometry.mono_config import class_size
from deepcrashtest.geometry.project import camera_rotation
from deepcrashtest.scenario import Camera

#: Box categories used, and the least box height and bottom-row offset below the horizon (px).
SIDE_CATEGORIES = ("car",)
MIN_BOX_H_PX = 15.0
MIN_BELOW_HORIZON_PX = 6.0
#: Boxes and distinct tracks needed, and tracks whose near side shows (the box's inner edge beyond
#: ``cx`` by more than SIDE_MIN_PX): they carry the focal length.
MIN_SIDE_BOXES = 40
MIN_SIDE_TRACKS = 4
SIDE_MIN_PX = 5.0
#: The band of inner-edge offsets from ``cx`` (fractions of the image width) whose boxes are used: nearer
#: the centre, cars crossing at junctions dominate; further out, near cars at wide angles depart from a
#: cuboid. PER_TRACK: one free aspect factor per track (else one for all).
BAND = (0.02, 0.3)
PER_TRACK = False
#: A track is used only while it keeps its lateral offset: the outer bottom corner of a car driving
#: along the camera's axis stays on one line through the axis point on the horizon, ``(u - cx) / (v_b -
#: v_h) = X / hc`` whatever its depth and whatever the focal length. Tracks whose ``X`` (m, at the
#: camera height) spreads more than ALIGN_TOL_M (robust sigma) over at least ALIGN_MIN_BOXES boxes are
#: crossing, turning or changing lane (or the ego turns) and are dropped.
ALIGN_TOL_M = float("inf")  # 0.3 m left too few tracks (KITTI) and none on the highway
ALIGN_MIN_BOXES = 5
#: Focal lengths tried, as factors of the starting one (log-spaced), and the Tukey constant (in
#: robust sigmas of the aspect residual).
GRID_LOG_SPAN = 0.8
GRID_STEPS = 161
TUKEY_C = 4.685
BOOTSTRAP = 40


def _aspect_pred(
    boxes: np.ndarray, cam: Camera, f: float, horizon_v: float, dims: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """(predicted box aspect w/h, valid) of the class cuboids placed at each box for focal length ``f`` px.

    ``boxes``: (N, 4) ``x1, y1, x2, y2`` px; ``dims``: (N, 3) length, width, height m. Camera: level
    frame x right, y down, z forward; pitch from the horizon row at ``f``; the ground ``y = height_m``."""
    cam_f = cam.model_copy(
        update={"fx": cam.fx * f / cam.fy, "fy": f, "pitch_rad": math.atan2(cam.cy - horizon_v, f), "roll_rad": 0.0}
    )
    R = camera_rotation(cam_f)
    x1, x2, y2 = boxes[:, 0], boxes[:, 2], boxes[:, 3]
    right = x1 > cam.cx  # all of the box right of the axis: its outer (right) edge is the near outer corner
    left = x2 < cam.cx
    u = np.where(right, x2, np.where(left, x1, 0.5 * (x1 + x2)))
    ray = np.column_stack([(u - cam.cx) / cam_f.fx, (y2 - cam.cy) / f, np.ones(len(u))]) @ R  # to the level frame
    valid = ray[:, 1] > 1e-6
    t = np.where(valid, cam.height_m / np.where(valid, ray[:, 1], 1.0), np.nan)
    gx, gz = t * ray[:, 0], t * ray[:, 2]
    L, W, H = dims[:, 0], dims[:, 1], dims[:, 2]
    xa = np.where(right, gx - W, np.where(left, gx, gx - 0.5 * W))  # the cuboid spans xa .. xa + W, gz .. gz + L
    xs = np.stack([xa, xa + W], axis=1)[:, [0, 1, 0, 1, 0, 1, 0, 1]]
    zs = np.stack([gz, gz + L], axis=1)[:, [0, 0, 1, 1, 0, 0, 1, 1]]
    ys = np.stack([np.full_like(H, cam.height_m), cam.height_m - H], axis=1)[:, [0, 0, 0, 0, 1, 1, 1, 1]]
    p = np.stack([xs, ys, zs], axis=2) @ R.T  # (N, 8, 3) camera frame
    z = np.maximum(p[..., 2], 1e-3)
    pu, pv = cam_f.fx * p[..., 0] / z, f * p[..., 1] / z
    w = pu.max(axis=1) - pu.min(axis=1)
    h = pv.max(axis=1) - pv.min(axis=1)
    valid &= (gz > 0) & (p[..., 2].min(axis=1) > 0.5) & (h > 0)
    return np.where(valid, w / np.where(h > 0, h, 1.0), np.nan), valid


def _side_boxes(tracks: pd.DataFrame, size: tuple[int, int], horizon_v: float) -> pd.DataFrame:
    """Detected, uncut car boxes tall enough and below the horizon."""
    w, h = size
    d = tracks
    if "state" in d.columns:
        d = d[d["state"] == "detected"]
    bh = d["y2"] - d["y1"]
    ok = (d["y1"] > 1) & (d["y2"] < h - 2) & (d["x1"] > 1) & (d["x2"] < w - 2) & (bh >= MIN_BOX_H_PX)
    ok &= d["category"].isin(SIDE_CATEGORIES) & (d["y2"] - horizon_v >= MIN_BELOW_HORIZON_PX)
    return d[ok]


def _aligned(d: pd.DataFrame, camera: Camera, horizon_v: float) -> pd.DataFrame:
    """The boxes of tracks that keep their lateral offset (see :data:`ALIGN_TOL_M`)."""
    u = np.where(d["x1"] > camera.cx, d["x2"], np.where(d["x2"] < camera.cx, d["x1"], 0.5 * (d["x1"] + d["x2"])))
    x = camera.height_m * (u - camera.cx) / (d["y2"] - horizon_v).to_numpy(float)
    g = pd.Series(x, index=d.index).groupby(d["track_id"])
    spread = g.transform(lambda v: 1.4826 * float(np.median(np.abs(v - np.median(v)))))
    n = g.transform("size")
    return d[(n >= ALIGN_MIN_BOXES) & (spread <= ALIGN_TOL_M)]


def _centred(r: np.ndarray, group: np.ndarray) -> np.ndarray:
    """``r`` (grid steps x boxes) minus each track's median over its boxes (the free factor ``k`` per track)."""
    out = np.full_like(r, np.nan)
    order = np.argsort(group, kind="stable")
    cuts = np.nonzero(np.diff(group[order]))[0] + 1
    for idx in np.split(order, cuts):
        out[:, idx] = r[:, idx] - np.nanmedian(r[:, idx], axis=1, keepdims=True)
    return out


def _fit(res: np.ndarray, scale: float) -> tuple[int, np.ndarray]:
    """(index of the best focal length on the grid, cost per grid step): Tukey cost of the centred
    log-aspect residuals ``res`` (grid steps x boxes) at a fixed residual ``scale``."""
    u = np.minimum(np.abs(res) / (TUKEY_C * scale), 1.0)
    rho = np.where(np.isfinite(u), 1 - (1 - u**2) ** 3, 1.0)  # Tukey's rho / (c^2 / 6); unplaced boxes: outliers
    cost = rho.sum(axis=1)
    return int(np.argmin(cost)), cost


def focal_from_sides(
    tracks: pd.DataFrame, size: tuple[int, int], camera: Camera, horizon_v: float, seed: int = 0, own_size: bool = False
) -> tuple[float, float, int] | None:
    """(focal length px, relative 1-sigma, tracks used) from the aspect of car boxes against their column.

    ``camera``: the current camera (its ``fy`` the starting point, ``cx``, ``cy``, ``height_m``);
    ``horizon_v``: the horizon row (px) measured from the boxes. None when fewer than
    :data:`MIN_SIDE_BOXES` boxes or :data:`MIN_SIDE_TRACKS` tracks with their side in view. ``own_size``:
    the cuboid of each box from its columns ``l, w, h`` (labels) instead of the class prior."""
    d = _aligned(_side_boxes(tracks, size, horizon_v), camera, horizon_v)
    off = np.maximum(d["x1"] - camera.cx, camera.cx - d["x2"]) / size[0]
    d = d[(off >= BAND[0]) & (off <= BAND[1])]
    if len(d) < MIN_SIDE_BOXES:
        return None
    side = (d["x1"] > camera.cx + SIDE_MIN_PX) | (d["x2"] < camera.cx - SIDE_MIN_PX)
    if d.loc[side, "track_id"].nunique() < MIN_SIDE_TRACKS:
        return None
    boxes = d[["x1", "y1", "x2", "y2"]].to_numpy(float)
    if own_size:  # each box's own cuboid (label columns l, w, h)
        dims = d[["l", "w", "h"]].to_numpy(float)
    else:
        dims = np.array([class_size(str(c)) for c in d["category"]])
    obs = (boxes[:, 2] - boxes[:, 0]) / (boxes[:, 3] - boxes[:, 1])
    grid = camera.fy * np.exp(np.linspace(-GRID_LOG_SPAN, GRID_LOG_SPAN, GRID_STEPS))
    pred = np.vstack([_aspect_pred(boxes, camera, f, horizon_v, dims)[0] for f in grid])
    ids = d["track_id"].to_numpy()
    uniq, group = np.unique(ids, return_inverse=True)
    res = _centred(np.log(obs)[None, :] - np.log(pred), group if PER_TRACK else np.zeros_like(group))
    r0 = res[GRID_STEPS // 2]
    r0 = r0[np.isfinite(r0)]
    scale = 1.4826 * float(np.median(np.abs(r0))) + 1e-3
    best, _ = _fit(res, scale)
    if best in (0, GRID_STEPS - 1):
        return None  # no minimum inside the range tried
    groups = [np.nonzero(group == i)[0] for i in range(len(uniq))]
    rng = np.random.default_rng(seed)
    boot = []
    for _ in range(BOOTSTRAP):
        pick = np.concatenate([groups[i] for i in rng.integers(0, len(groups), len(groups))])
        boot.append(math.log(grid[_fit(res[:, pick], scale)[0]]))
    rel = float(np.std(boot))
    return float(grid[best]), rel, len(uniq)


def main() -> None:
    import argparse
    import pickle
    from pathlib import Path

    from deepcrashtest.datasets.kitti.files import KittiSequence, read_calib, read_labels
    from deepcrashtest.eval.kitti_mono import DEFAULT_MONO, image_tracks, prepare_mono
    from deepcrashtest.geometry.camera import default_camera
    from deepcrashtest.geometry.selfcalib import horizon_and_height

    global PER_TRACK
    ap = argparse.ArgumentParser()
    ap.add_argument("--boxes", choices=["tracks", "labels"], default="tracks")
    ap.add_argument("--dims", choices=["prior", "true"], default="prior")
    ap.add_argument("--per-track", action="store_true")
    ap.add_argument("--cache", default="/tmp/selfcalib_diag")
    ap.add_argument("--csv", help="an extract's tracks.csv (1280x720 video) instead of KITTI")
    args = ap.parse_args()
    PER_TRACK = args.per_track
    if args.csv:
        t = pd.read_csv(args.csv)
        hh = horizon_and_height(t, (1280, 720))
        cam = default_camera(1280, 720).model_copy(update={"height_m": hh[2]}) if hh else None
        print(None if cam is None or hh is None else focal_from_sides(t, (1280, 720), cam, hh[0]))
        return
    data = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "kitti_tracking"
    size = (1242, 375)
    errors = []
    for s in [s for s in range(21) if s not in (3, 8, 10)]:
        seq = KittiSequence(data, s)
        if args.boxes == "labels":
            t = read_labels(seq.labels)
            t = t[(t["type"] == "Car") & (t["occluded"] <= 1) & (t["truncated"] <= 0)].assign(category="car")
        else:
            f = Path(args.cache) / f"tracks_{s:04d}.pkl"
            t = pickle.loads(f.read_bytes()) if f.exists() else image_tracks(prepare_mono(data, s), DEFAULT_MONO)
        hh = horizon_and_height(t, size)
        fy_true = float(read_calib(seq.calib).P2[1, 1])
        if hh is None:
            continue
        cam = default_camera(*size).model_copy(update={"height_m": hh[2]})
        est = focal_from_sides(t, size, cam, hh[0], own_size=args.dims == "true" and args.boxes == "labels")
        if est is not None:
            errors.append(100 * (est[0] / fy_true - 1))
        line = (
            "-"
            if est is None
            else f"{est[0]:.0f} px ({errors[-1]:+.1f} %, 1-sigma {100 * est[1]:.0f} %, {est[2]} tracks)"
        )
        print(f"{s:04d} {line}", flush=True)
    print(f"median |error| {np.median(np.abs(errors)):.1f} % over {len(errors)} sequences")


if __name__ == "__main__":
    main()
