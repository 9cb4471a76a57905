"""Ego-motion on real dashcam clips: a stopped ego is a measurement (speed 0), a moving one moves."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from conftest import DATA, need
from deepcrashtest.geometry.camera import calibrate_chessboard, default_camera, detect_dashboard_rows
from deepcrashtest.geometry.egomotion import MAX_RATE_HZ, EgoMotionEstimator
from deepcrashtest.pipeline.geometry_pass import estimate_camera

DAD = DATA / "crash_dad"


def _frames(path: Path, count: int) -> list[np.ndarray]:
    cap = cv2.VideoCapture(str(need(path)))
    out = []
    while len(out) < count:
        ok, img = cap.read()
        if not ok:
            break
        out.append(img)
    cap.release()
    return out


def _run(path: Path, count: int, fps: float = 20.0) -> tuple[EgoMotionEstimator, np.ndarray]:
    imgs = _frames(path, count)
    h, w = imgs[0].shape[:2]
    est = EgoMotionEstimator(default_camera(w, h), mask_bottom_rows=detect_dashboard_rows(imgs[::4]))
    for i, img in enumerate(imgs):
        est.update(img, i / fps)
    return est, est.result().speed


def test_stopped_dashcam_ego_is_a_measurement_not_a_failure():
    """DAD 512: the ego waits behind an SUV (the scene is still, a scooter passes)."""
    est, speed = _run(DAD / "dad_000512.mp4", 30)
    res = est.result()
    assert res.static and np.all(speed == 0.0) and res.valid.all()
    assert not any("too few" in w for w in res.warnings)


def test_moving_dashcam_ego_is_not_stopped():
    """DAD 478: the ego drives down a street lined with parked cars (measured 2.5-5.6 m/s, default camera)."""
    est, speed = _run(DAD / "dad_000478.mp4", 30)
    res = est.result()
    assert not res.static and res.valid[1:].mean() >= 0.8  # measured 26 of 29 pairs
    assert 1.0 < float(np.median(speed[5:])) < 15.0


def test_calibrated_highway_dashcam_speed_is_metric():
    """Udacity highway clip with its own chessboard calibration (and the 1.3 m dashcam height prior):
    the road-plane scale gives a highway speed (measured 115 km/h over frames 5-49; the default 90 deg
    camera gives about half, as the scale is proportional to the focal length)."""
    video = DATA / "dashcam_udacity" / "highway_project_video.mp4"
    imgs = _frames(video, 50)
    cam, _, _ = calibrate_chessboard(need(DATA / "dashcam_udacity" / "camera_calibration"), max_images=8)
    est = EgoMotionEstimator(
        cam.model_copy(update={"height_m": 1.3}), mask_bottom_rows=detect_dashboard_rows(imgs[::5])
    )
    for i, img in enumerate(imgs):
        est.update(img, i / 25.0)
    res = est.result()
    assert not res.static and res.valid.mean() >= 0.9
    assert 80.0 < 3.6 * float(np.median(res.speed[5:])) < 130.0


def test_moving_dashcam_with_date_overlay_is_not_stopped():
    """CCD 80 (10 fps, camera as extract estimates it): the ego drives down a tree-lined road; the
    burned-in date's sharp corners outlast the blurred scene's, and a median over points read 0 px of
    parallax (main: 31 of 49 frames "stopped", median 0 km/h). The median over image cells sees the
    scene move (measured: no stopped pair, 8-13 m/s over frames 13-21)."""
    imgs = _frames(DATA / "crash_ccd" / "ccd_000080.mp4", 30)
    h, w = imgs[0].shape[:2]
    cam, rows, _ = estimate_camera(imgs[:21], default_camera(w, h))
    est = EgoMotionEstimator(cam, mask_bottom_rows=rows)
    for i, img in enumerate(imgs):
        est.update(img, i / 10.0)
    res = est.result()
    assert not res.static and not any(s.raw_speed == 0.0 for s in est._states)
    assert float(np.median(res.speed[1:])) > 3.0


def _decoded(path: Path, count: int) -> tuple[list[np.ndarray], list[float]]:
    """The first ``count`` frames of a clip and their times (s) from the container, as extract sees them."""
    from deepcrashtest.video.source import open_video

    imgs, times = [], []
    with open_video(need(path)) as source:
        for frame in source:
            imgs.append(frame.image)
            times.append(frame.time)
            if len(imgs) == count:
                break
    return imgs, times


@pytest.mark.parametrize(
    ("clip", "count", "step"),
    [
        ("dashcam_udacity/highway_project_video.mp4", 21, 2),  # 25 fps: every other frame (12.5 Hz)
        ("crash_dad/dad_000478.mp4", 12, 1),  # 20 fps: every frame
        ("crash_ccd/ccd_000053.mp4", 12, 1),  # 10 fps: every frame
    ],
)
def test_rate_cap_measures_the_frames_at_most_max_rate_hz_apart(clip: str, count: int, step: int):
    """MAX_RATE_HZ = 20: ego-motion measures the first frame and then each frame >= 0.045 s after the last
    measured one, on the clips' own timestamps (a 25 fps clip every other frame; lower caps lost accuracy on the
    highway and DAD clips, README Performance); the lanes' gate (extract's geometry pass) takes the same
    frames; every frame still has a state, and a frame between two measured ones lies on the straight line
    between them (interpolated in time)."""
    from deepcrashtest.pipeline.geometry_pass import _RateGate

    assert MAX_RATE_HZ == 20.0
    imgs, times = _decoded(DATA / clip, count)
    h, w = imgs[0].shape[:2]
    est = EgoMotionEstimator(default_camera(w, h), mask_bottom_rows=detect_dashboard_rows(imgs[::4]))
    gate = _RateGate(MAX_RATE_HZ)
    lanes = [k for k, t in enumerate(times) if gate.take(t)]
    for img, t in zip(imgs, times, strict=True):
        est.update(img, t)
    res = est.result()
    measured = [s.frame for s in est._states]
    assert measured == list(range(0, count, step)) == lanes
    assert len(res) == count and list(res.frame) == list(range(count))
    assert not res.static and float(np.median(res.speed)) > 2.0  # all three egos drive
    t = np.asarray(times)
    for a, b in zip(measured[:-1], measured[1:], strict=True):
        for k in range(a + 1, b):
            u = (t[k] - t[a]) / (t[b] - t[a])
            for arr in (res.x, res.y, res.yaw, res.speed):
                assert arr[k] == pytest.approx((1 - u) * arr[a] + u * arr[b], abs=1e-9)


def test_10fps_video_gives_the_same_ego_motion_as_without_a_rate_cap():
    """A 10 fps clip (KITTI, the CCD crash clips) is measured at every frame under the cap: the result is
    the uncapped estimator's, bit for bit."""
    imgs, times = _decoded(DATA / "crash_ccd" / "ccd_000053.mp4", 20)
    h, w = imgs[0].shape[:2]
    rows = detect_dashboard_rows(imgs[::4])
    runs = []
    for rate in (MAX_RATE_HZ, None):
        est = EgoMotionEstimator(default_camera(w, h), mask_bottom_rows=rows, max_rate_hz=rate)
        for img, t in zip(imgs, times, strict=True):
            est.update(img, t)
        runs.append(est.result())
    capped, every = runs
    for name in ("frame", "t", "x", "y", "yaw", "speed", "yaw_rate", "valid", "tilt"):
        assert np.array_equal(getattr(capped, name), getattr(every, name)), name
    assert float(np.median(capped.speed)) > 2.0


def test_road_crop_box_stays_inside_the_image_when_the_road_warps_off_it():
    """The road points warped by the last homography can all land beyond an image edge (a real DAD clip
    raised a broadcast ValueError there): the crop box is still a non-empty box inside the image."""
    from deepcrashtest.geometry.egomotion import _crop_box

    w, h = 640, 360
    for pts in ([[10.0, 900.0], [200.0, 950.0]], [[2000.0, 10.0], [2100.0, 20.0]], [[-50.0, -60.0], [-10.0, -5.0]]):
        x0, y0, x1, y1 = _crop_box(np.array(pts), w, h, margin=8, align=4)
        assert 0 <= x0 < x1 <= w and 0 <= y0 < y1 <= h
    assert _crop_box(np.array([[100.0, 100.0], [300.0, 200.0]]), w, h, margin=8, align=4) == (92, 92, 308, 208)


def _two_seconds(path: Path, fps: float) -> list[np.ndarray]:
    return _frames(path, int(2 * fps) + 1)


def test_static_overlay_mask_covers_burned_in_text_not_the_scene():
    """CCD 14 (10 fps, a GPS date/position/speed line burned in at rows ~688-708): the still-pixel mask
    covers that line and leaves the road and the scene above it; none for a stopped camera (DAD 512:
    the whole scene stands still) or a plain moving scene (KITTI odometry seq00, no overlay)."""
    from deepcrashtest.geometry.camera import static_overlay_mask

    imgs = _two_seconds(DATA / "crash_ccd" / "ccd_000014.mp4", 10.0)
    mask = static_overlay_mask(imgs)
    assert mask is not None and mask.shape == imgs[0].shape[:2]
    assert mask[686:712, 540:1240].mean() > 0.8  # measured 1.0 (glyphs, gaps closed, dilated)
    assert mask[:680].mean() < 0.01  # measured 0.002 (the top border row)
    assert static_overlay_mask(_frames(DAD / "dad_000512.mp4", 41)) is None
    kitti = sorted(need(DATA / "kitti_odometry" / "seq00_frames0000-0159" / "image_0").glob("*.png"))[:21]
    assert static_overlay_mask([cv2.imread(str(p)) for p in kitti]) is None


def test_no_road_corner_is_seeded_on_a_burned_in_overlay():
    """CCD 14 with extract's camera estimate and the overlay mask of the first 2 s: once the horizon is learned
    (~row 525) the road region ahead reaches into the date/speed line (rows ~688-708), where the road-corner
    quota (low corner threshold) finds the glyphs' sharp corners first; with the overlay mask no road
    corner is seeded there (and no point there enters the road-scale fit: ``_off_overlay``), while scene
    corners may stay on it as before (measured 9 tracked)."""
    from deepcrashtest.geometry.camera import static_overlay_mask

    imgs = _frames(DATA / "crash_ccd" / "ccd_000014.mp4", 12)
    first = _two_seconds(DATA / "crash_ccd" / "ccd_000014.mp4", 10.0)
    cam, rows, _ = estimate_camera(first, default_camera(1280, 720))
    on_text = []
    for mask in (None, static_overlay_mask(first)):
        est = EgoMotionEstimator(cam, mask_bottom_rows=rows, still_mask=mask)
        for i, img in enumerate(imgs):
            est.update(img, i / 10.0)
        road = est._road_mask(est._static_mask((540, 960), np.zeros((0, 4)))) > 0  # work px (960 wide)
        text = np.zeros_like(road)
        text[int(690 * 0.75) : int(708 * 0.75), int(540 * 0.75) : int(1240 * 0.75)] = True
        p = est._p
        on_text.append((float(road[text].mean()), int(np.sum(~est._off_overlay(p)))))
    assert on_text[0][0] > 0.01  # without the mask the road region reaches into the text line (measured 0.026)
    assert on_text[1][0] == 0.0


def test_ego_yaw_follows_a_calibrated_focal_length():
    """KITTI odometry seq00 frames 0-159 (a -85.8 deg turn) measured with the focal length assumed 20 % short
    (0.8 x 718 px; height / 0.8 so focal x height, the speed's scale, stays right): the turn reads -105.8 deg
    (a rotation is seen as focal x angle). Rescaled for the calibrated focal length (``rescaled``, as
    ``extract`` does once the self-calibration measures one) it reads -84.6 deg; speeds and path length stay
    as they were, and a ratio of 1 only scales the metres (extract today)."""
    from deepcrashtest.datasets.kitti.files import KITTI_CAMERA_HEIGHT_M, read_poses
    from deepcrashtest.eval.egomotion import egomotion_errors, frame_times, read_odometry_calib
    from deepcrashtest.geometry.egomotion import rescaled
    from deepcrashtest.scenario import Camera

    folder = need(DATA / "kitti_odometry" / "seq00_frames0000-0159")
    images = [cv2.imread(str(p), cv2.IMREAD_GRAYSCALE) for p in sorted((folder / "image_0").glob("*.png"))]
    poses = read_poses(folder / "poses.txt")[: len(images)]
    K, times = read_odometry_calib(folder), frame_times(folder, len(images))
    cam = Camera(fx=0.8 * K[0, 0], fy=0.8 * K[1, 1], cx=K[0, 2], cy=K[1, 2], height_m=KITTI_CAMERA_HEIGHT_M / 0.8)
    est = EgoMotionEstimator(cam)
    for img, t in zip(images, times, strict=True):
        est.update(img, float(t))
    ego = est.result()
    before = egomotion_errors(ego, poses, times)
    after = egomotion_errors(rescaled(ego, 1.0, 0.8), poses, times)
    assert before["yaw_error_final_deg"] > 10.0  # measured 19.9
    assert after["yaw_error_final_deg"] < 3.0  # measured 1.2
    assert after["distance_error_pct"] == before["distance_error_pct"]  # measured 2.05
    same = rescaled(ego, 1.5, 1.0)
    np.testing.assert_allclose(same.x, 1.5 * ego.x)
    np.testing.assert_allclose(same.yaw, ego.yaw)


def test_speed_filter_logs_every_reading_and_what_it_did_with_it():
    """CCD 53 (10 fps, default camera): the speed filter's log (``bench/speed_filter_readings.py``) holds
    every road-scale or stopped reading the estimator fed it, in order, with its outcome. On this clip the
    filter starts on 19 km/h and fuses 26 / 25 (frames 1-4); frames 36-38 read 10 / 8 / 3 km/h (1-sigma
    0.2-0.6), each gated, until the fourth in a row re-starts it (frame 39, 3 km/h): the first-reading hold
    and re-start that README's ego-speed notes measure."""
    imgs = _frames(DATA / "crash_ccd" / "ccd_000053.mp4", 42)
    h, w = imgs[0].shape[:2]
    est = EgoMotionEstimator(default_camera(w, h), mask_bottom_rows=detect_dashboard_rows(imgs[::4]))
    raws = []
    for i, img in enumerate(imgs):
        state = est.update(img, i / 10.0)
        raws.append((i, state.raw_speed))
    log = est._filter.readings
    fed = [(i, z) for i, z in raws if z is not None]
    assert [(s + 1, z) for s, z, _, _ in log] == [(i, pytest.approx(z)) for i, z in fed]
    assert log[0][3] == "start" and {o for *_, o in log} <= {"start", "fused", "gated", "restart"}
    assert [o for *_, o in log if o != "fused"] == ["start", "gated", "gated", "gated", "restart"]
    assert all(v > 0 for _, _, v, _ in log)


def test_road_scale_of_a_dashcam_clip_skips_still_points_and_sideways_pairs():
    """CCD 14 (10 fps, 58 km/h, extract's camera estimate, frames 0-43 before the crash): the road region
    holds points that hardly move while the scene does (a dashboard reflection at the bottom left, measured 45 %
    of the road-region points under 0.1 of the scene's parallax, against 0.8 % on KITTI odometry), and a third
    of the essential matrices put the camera moving sideways (75-113 deg off its travel; KITTI at most 11).
    With the options ``max_travel_dev_deg=30`` no pair > 30 deg off the travel gives a road-scale reading, and
    with ``road_flow_share=0.05`` every point of every road-scale fit moves at least 5 % of the scene's
    parallax. Without them, each happened (the still points were most of two of the three fits with road users
    masked; readings 20 / 9 / 6 km/h at the default camera)."""
    from deepcrashtest.geometry import egomotion

    imgs = _frames(DATA / "crash_ccd" / "ccd_000014.mp4", 44)
    cam, rows, _ = estimate_camera(_two_seconds(DATA / "crash_ccd" / "ccd_000014.mp4", 10.0), default_camera(1280, 720))
    est = EgoMotionEstimator(cam, mask_bottom_rows=rows, road_flow_share=0.05, max_travel_dev_deg=30.0)
    solve, fit = est._solve, egomotion.fit_plane_motion
    pairs: list[tuple[float, float]] = []  # (parallax work px, smallest flow of a fitted road point)
    aside: list[tuple[bool, bool]] = []  # per solved pair: sideways, and whether it gave a reading

    def solve_logged(p0, p1, h, moving=False, parallax=0.0):  # type: ignore[no-untyped-def]
        out = solve(p0, p1, h, moving, parallax)
        if out is not None:
            sideways = est._travel is not None and float(-out[3].T @ out[4] @ est._travel) < np.cos(np.radians(30))
            aside.append((sideways, bool(np.isfinite(out[0]))))
            if moving and pairs and np.isnan(pairs[-1][0]):
                pairs[-1] = (parallax, pairs[-1][1])
        return out

    def fit_logged(x0, p1, K, *a, **kw):  # type: ignore[no-untyped-def]
        p0 = x0[:, :2] * [K[0, 0], K[1, 1]] + [K[0, 2], K[1, 2]]
        pairs.append((float("nan"), float(np.min(np.linalg.norm(p1 - p0, axis=1)))))
        return fit(x0, p1, K, *a, **kw)

    est._solve = solve_logged  # type: ignore[method-assign]
    egomotion.fit_plane_motion = fit_logged  # type: ignore[assignment]
    try:
        for i, img in enumerate(imgs):
            est.update(img, i / 10.0)
    finally:
        egomotion.fit_plane_motion = fit  # type: ignore[assignment]
    fitted = [(parallax, flow) for parallax, flow in pairs if np.isfinite(parallax)]
    assert len(fitted) >= 5 and all(flow >= 0.05 * parallax - 1e-6 for parallax, flow in fitted)
    assert sum(s for s, _ in aside) >= 3  # measured 9
    assert not any(s and reading for s, reading in aside)


def test_sparse_readings_are_fused_not_held_against():
    """KITTI odometry seq00 frames 0-159 (calibrated camera) with only every 10th road-scale reading given to
    the speed filter, as sparse as on city dashcam clips: the readings err 2.8 % (median) and their stated
    sigma covers that, yet without ``speed_hold_accel`` the held speed's variance hardly grew between them and
    5 of the 16 were gated (output median speed error 9.4 %). With ``speed_hold_accel=1`` (an option, not the
    default: README) none is gated and the output errs 4.4 % (every reading: 2.2 %)."""
    from deepcrashtest.datasets.kitti.files import KITTI_CAMERA_HEIGHT_M, read_poses
    from deepcrashtest.eval.egomotion import egomotion_errors, frame_times, read_odometry_calib
    from deepcrashtest.scenario import Camera

    folder = need(DATA / "kitti_odometry" / "seq00_frames0000-0159")
    images = [cv2.imread(str(p), cv2.IMREAD_GRAYSCALE) for p in sorted((folder / "image_0").glob("*.png"))]
    poses = read_poses(folder / "poses.txt")[: len(images)]
    K, times = read_odometry_calib(folder), frame_times(folder, len(images))
    cam = Camera(fx=K[0, 0], fy=K[1, 1], cx=K[0, 2], cy=K[1, 2], height_m=KITTI_CAMERA_HEIGHT_M)
    est = EgoMotionEstimator(cam, speed_hold_accel=1.0)
    step, seen = est._filter.step, [0]

    def every_tenth(dt: float, z: float | None, var: float) -> float:
        if z is not None:
            seen[0] += 1
            z = z if (seen[0] - 1) % 10 == 0 else None
        return step(dt, z, var)

    est._filter.step = every_tenth  # type: ignore[method-assign]
    for img, t in zip(images, times, strict=True):
        est.update(img, float(t))
    outcomes = [o for *_, o in est._filter.readings]
    assert len(outcomes) >= 12 and "gated" not in outcomes  # measured 16 readings
    assert egomotion_errors(est.result(), poses, times)["speed_error_median_pct"] < 6.0  # measured 4.36


def test_speeds_before_a_cut_ignore_the_readings_after_it():
    """ccd_000053 (10 fps, crash at labelled frame 33): with ``speed_hold_accel=1`` its road-scale readings
    after the crash were fused and the RTS smoother carried the crash's slowing back before it (fidelity IoU
    0.73 -> 0.53). ``result(cut_time)`` smooths the speeds up to the cut from the readings up to it only: they
    are those of the stream stopped at the cut, while the uncut result moved them. With a lone reading before
    the cut, nothing is cut."""
    imgs = _frames(DATA / "crash_ccd" / "ccd_000053.mp4", 60)
    h, w = imgs[0].shape[:2]
    est = EgoMotionEstimator(
        default_camera(w, h), mask_bottom_rows=detect_dashboard_rows(imgs[::4]), speed_hold_accel=1.0
    )
    crash = 33
    for i, img in enumerate(imgs):
        est.update(img, i / 10.0)
        if i == crash:
            stopped = est.result().speed
    whole, cut = est.result().speed[: crash + 1], est.result(cut_time=crash / 10.0).speed[: crash + 1]
    assert np.allclose(cut, stopped, atol=1e-9)
    assert np.max(np.abs(whole - stopped)) > 0.5
    # one reading (the filter's start, step 0 = state 1) up to the cut: not cut, the later readings count
    assert np.array_equal(est.result(cut_time=0.15).speed, est.result().speed)


def _fixed_in_fits(est: EgoMotionEstimator, frames: list[tuple[np.ndarray, float]]) -> tuple[int, int, int]:
    """Run ``est`` over (image, time) ``frames``; returns (road-plane fits, road points of those fits, fitted
    road points that stay put: moving less than 0.1 of the rotation's flow where that flow is >= 3 work px)."""
    from deepcrashtest.geometry import egomotion

    fit = egomotion.fit_plane_motion
    counts = [0, 0, 0]

    def fit_logged(x0, p1, K, R, *a, **kw):  # type: ignore[no-untyped-def]
        p0 = x0[:, :2] * [K[0, 0], K[1, 1]] + [K[0, 2], K[1, 2]]
        q = x0 @ (K @ R).T
        rot = np.linalg.norm(q[:, :2] / q[:, 2:3] - p0, axis=1)
        still = np.linalg.norm(p1 - p0, axis=1)
        counts[0] += 1
        counts[1] += len(p0)
        counts[2] += int(np.sum((rot >= 3.0) & (still < 0.1 * rot)))
        return fit(x0, p1, K, R, *a, **kw)

    egomotion.fit_plane_motion = fit_logged  # type: ignore[assignment]
    try:
        for img, t in frames:
            est.update(img, t)
    finally:
        egomotion.fit_plane_motion = fit  # type: ignore[assignment]
    return counts[0], counts[1], counts[2]


def test_road_scale_fits_leave_out_points_fixed_to_the_camera():
    """CCD 14 (10 fps, 58 km/h, a shaking camera: rotation flows of 5-20 px a frame pair; extract's camera
    estimate, frames 0-43 before the crash): the road region holds points fixed to the camera (the dashboard and
    its reflection at the bottom left) that stay put while the rotation moves every scene point by many pixels.
    Without ``fixed_flow_share`` (0, the default) 17 of them entered its road-plane fits (most of the points of
    its low readings: 9 / 6 km/h at the default camera); with the option at 0.1 none does (29 fits, 753 points)."""
    video = DATA / "crash_ccd" / "ccd_000014.mp4"
    imgs = _frames(video, 44)
    cam, rows, _ = estimate_camera(_two_seconds(video, 10.0), default_camera(1280, 720))
    frames = [(img, i / 10.0) for i, img in enumerate(imgs)]
    _, _, fixed_before = _fixed_in_fits(EgoMotionEstimator(cam, mask_bottom_rows=rows, fixed_flow_share=0.0), frames)
    est = EgoMotionEstimator(cam, mask_bottom_rows=rows, fixed_flow_share=0.1)
    fits, points, fixed = _fixed_in_fits(est, frames)
    assert fixed_before >= 10 and fixed == 0
    assert fits >= 1 and points >= 12


def test_no_kitti_road_point_counts_as_fixed_to_the_camera():
    """KITTI odometry seq06 (calibrated camera): no road point stays put against the rotation's flow, so the
    camera-fixed test (``fixed_flow_share=0.1``) leaves its road-plane fits and speeds as they were (50 fits,
    3,302 points)."""
    from deepcrashtest.datasets.kitti.files import KITTI_CAMERA_HEIGHT_M
    from deepcrashtest.eval.egomotion import frame_times, read_odometry_calib
    from deepcrashtest.scenario import Camera

    folder = need(DATA / "kitti_odometry" / "seq06_frames0000-0050")
    images = [cv2.imread(str(p), cv2.IMREAD_GRAYSCALE) for p in sorted((folder / "image_0").glob("*.png"))]
    K, times = read_odometry_calib(folder), frame_times(folder, len(images))
    cam = Camera(fx=K[0, 0], fy=K[1, 1], cx=K[0, 2], cy=K[1, 2], height_m=KITTI_CAMERA_HEIGHT_M)
    frames = [(img, float(t)) for img, t in zip(images, times, strict=True)]
    on, off = EgoMotionEstimator(cam, fixed_flow_share=0.1), EgoMotionEstimator(cam)
    fits, points, fixed = _fixed_in_fits(on, frames)
    _fixed_in_fits(off, frames)
    assert fits >= 40 and points >= 40 * 12 and fixed == 0
    assert np.array_equal(on.result().speed, off.result().speed)


def test_the_warning_tells_pairs_without_features_from_pairs_without_a_consistent_motion():
    """DAD 478 (camera as extract calibrates it from its first 2 s): hundreds of points tracked in every pair, yet
    the camera motion of a quarter of them fits no single turn and translation (swaying trees line the street):
    the warning says that, not "too few trackable features" (the features are there); a dark clip's pairs are
    the ones without features."""
    imgs = _frames(DAD / "dad_000478.mp4", 100)
    cam, rows, _ = estimate_camera(imgs[:40], default_camera(imgs[0].shape[1], imgs[0].shape[0]))
    est = EgoMotionEstimator(cam, mask_bottom_rows=rows)
    for i, img in enumerate(imgs):
        est.update(img, i / 20.0)
    res = est.result()
    text = " ".join(w for w in res.warnings if "not measured" in w)
    assert "gave no consistent camera motion" in text and "too few trackable" not in text
    dark = EgoMotionEstimator(default_camera(640, 360))
    for i in range(12):
        dark.update(np.full((360, 640, 3), 3, np.uint8), i / 10)
    assert any("too few trackable" in w and "consistent" not in w for w in dark.result().warnings)


def test_an_ego_speed_barely_measured_says_so():
    """CCD 487 (a pickup at highway speed on a textureless rural road, 10 fps, camera as extract calibrates it):
    the road gives no metric scale in any pair, the speed stays at the filter's 0 km/h, and the warnings said
    nothing about it; now one says the speed is barely measured. DAD 478, measured all along, does not get it."""
    imgs = _frames(DATA / "crash_ccd" / "ccd_000487.mp4", 50)
    cam, rows, _ = estimate_camera(imgs[:20], default_camera(imgs[0].shape[1], imgs[0].shape[0]))
    est = EgoMotionEstimator(cam, mask_bottom_rows=rows)
    for i, img in enumerate(imgs):
        est.update(img, i / 10.0)
    res = est.result()
    assert not res.static
    assert any("barely measured" in w for w in res.warnings)
    est, _ = _run(DAD / "dad_000478.mp4", 30)
    assert not any("barely measured" in w for w in est.result().warnings)


def _textureless_road(img: np.ndarray, horizon_v: int = 190) -> np.ndarray:
    """The frame with its road (a trapezoid from the bottom corners up to the horizon) smoothed flat, as a fresh
    asphalt or a snowed-over road films: no corner there to track."""
    h, w = img.shape[:2]
    pts = np.array(
        [[0, h], [0, h - 30], [int(0.38 * w), horizon_v + 8], [int(0.62 * w), horizon_v + 8], [w, h - 30], [w, h]],
        np.int32,
    )
    mask = np.zeros(img.shape[:2], np.uint8)
    cv2.fillPoly(mask, [pts], 255)
    return np.where(mask > 0, cv2.GaussianBlur(img, (0, 0), 20), img)


def _compressed(img: np.ndarray, quality: int = 50) -> np.ndarray:
    """The frame through JPEG at ``quality``, as a dashcam's or a video site's encoder leaves it."""
    return cv2.imdecode(cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, quality])[1], cv2.IMREAD_UNCHANGED)


def test_a_textureless_road_still_gives_the_speed_from_the_ground_beside_it():
    """KITTI odometry seq06 with its road smoothed flat (and JPEG-compressed): the road plane gives no metric scale in
    any pair, and the speed stayed at the filter's 0 (median error 100 %). The ground under the scene's standing
    points (kerbs, walls, parked cars: the envelope below them) now gives it: median speed error 17 % (the road
    itself, unsmoothed: 0.8 %), path length within 2 %; the warning says where the speed comes from."""
    from deepcrashtest.datasets.kitti.files import KITTI_CAMERA_HEIGHT_M, read_poses
    from deepcrashtest.eval.egomotion import egomotion_errors, frame_times, read_odometry_calib
    from deepcrashtest.scenario import Camera

    folder = need(DATA / "kitti_odometry" / "seq06_frames0000-0050")
    images = [
        _compressed(_textureless_road(cv2.imread(str(p), cv2.IMREAD_GRAYSCALE)))
        for p in sorted(folder.glob("image_0/*.png"))
    ]
    K = read_odometry_calib(folder)
    cam = Camera(fx=K[0, 0], fy=K[1, 1], cx=K[0, 2], cy=K[1, 2], height_m=KITTI_CAMERA_HEIGHT_M)
    times = frame_times(folder, len(images))
    est = EgoMotionEstimator(cam)
    for img, t in zip(images, times, strict=True):
        est.update(img, float(t))
    assert not [r for r in est._filter.readings if r[3] != "gated"]  # the road gave no reading
    res = est.result()
    errors = egomotion_errors(res, read_poses(folder / "poses.txt")[: len(images)], times)
    assert errors["speed_error_median_pct"] < 30.0
    assert errors["distance_error_pct"] < 10.0
    assert any("ground under the scene's standing points" in w for w in res.warnings)


def test_the_ground_envelope_reads_the_metres_travelled_from_points_standing_on_the_ground():
    """A camera 1.5 m over a flat road moves 1.2 m forward and turns 2 deg between two frames; 40 of the 120 points
    it tracks lie on the road, the rest on walls and cars beside it (up to 3.5 m above it). Triangulated at unit
    baseline, the points' lower envelope is the road: the metres travelled come back within 1 %; points above the
    camera's own height say nothing of the ground and are left out."""
    from deepcrashtest.geometry.road_motion import ground_envelope_scale

    rng = np.random.default_rng(0)
    ground = np.column_stack([rng.uniform(-6, 6, 40), np.full(40, 1.5), rng.uniform(6, 30, 40)])
    standing = np.column_stack([rng.choice([-7.0, 7.0], 80), rng.uniform(-2.0, 1.3, 80), rng.uniform(6, 40, 80)])
    pts = np.vstack([ground, standing])  # camera frame: x right, y down, z forward (m)
    yaw = np.radians(2.0)
    R = np.array([[np.cos(yaw), 0, np.sin(yaw)], [0, 1, 0], [-np.sin(yaw), 0, np.cos(yaw)]])
    t = -R @ np.array([0.0, 0.0, 1.2])  # the second camera 1.2 m ahead: x1 = R x0 + t
    moved = pts @ R.T + t
    x0, x1 = pts[:, :2] / pts[:, 2:], moved[:, :2] / moved[:, 2:]
    found = ground_envelope_scale(x0, x1, R, t / np.linalg.norm(t), np.array([0.0, 1.0, 0.0]), 1.5)
    assert found is not None
    assert found[0] == pytest.approx(1.2, rel=0.01)
    assert len(ground) <= found[1] <= int((pts[:, 1] > 0).sum())  # only points under the camera's height count


def _seq06_speed_error(tmp_path: Path, repeat: int) -> float:
    """Median speed error (%) of the ego-motion of KITTI odometry seq06 (10 Hz) written as an H.264 video at 10 x
    ``repeat`` fps, each frame shown ``repeat`` times (a clip re-encoded at a higher frame rate), read back as
    extract reads it."""
    from deepcrashtest.datasets.kitti.files import KITTI_CAMERA_HEIGHT_M, read_poses
    from deepcrashtest.eval.egomotion import egomotion_errors, read_odometry_calib
    from deepcrashtest.scenario import Camera
    from deepcrashtest.video.writer import VideoWriter

    folder = need(DATA / "kitti_odometry" / "seq06_frames0000-0050")
    images = [cv2.imread(str(p)) for p in sorted(folder.glob("image_0/*.png"))]
    h, w = images[0].shape[:2]
    path = tmp_path / f"seq06_x{repeat}.mp4"
    with VideoWriter(path, 10.0 * repeat, w, h, crf=18) as writer:
        for img in images:
            for _ in range(repeat):
                writer.write(img)
    decoded, times = _decoded(path, len(images) * repeat)
    K = read_odometry_calib(folder)
    est = EgoMotionEstimator(Camera(fx=K[0, 0], fy=K[1, 1], cx=K[0, 2], cy=K[1, 2], height_m=KITTI_CAMERA_HEIGHT_M))
    for img, t in zip(decoded, times, strict=True):
        est.update(img[:h, :w], t)
    res = est.result()
    first = np.arange(0, len(decoded), repeat)  # each picture's first frame: the time it was taken
    res.frame, res.t = res.frame[first] // repeat, res.t[first]
    for name in ("x", "y", "yaw", "speed", "yaw_rate", "valid"):
        setattr(res, name, getattr(res, name)[first])
    poses = read_poses(folder / "poses.txt")[: len(images)]
    return float(egomotion_errors(res, poses, np.asarray(res.t))["speed_error_median_pct"])


def test_frames_repeated_by_a_higher_frame_rate_give_the_speed_of_the_original(tmp_path: Path):
    """A clip re-encoded at a higher frame rate shows each picture several times: measured across a repeat the
    camera stands still, and the next new picture's motion lands on one frame interval (KITTI seq06 through H.264:
    median speed error 0.6 % at 10 fps; at 30 fps, each frame three times, 23 % with the repeats measured). Repeats
    are not measured (``video.repeats.RepeatWatch``): 1.5 %."""
    assert _seq06_speed_error(tmp_path, 1) < 3.0
    assert _seq06_speed_error(tmp_path, 3) < 3.0


def test_the_ego_speed_on_the_overlay_or_given_sets_the_scenes_scale(tmp_path):
    """ccd_000014's GPS overlay reads 57-59 km/h before the crash; from the images alone its speed is ~25 km/h (the
    focal length of a straight drive is not observable: docs/ego-speed.md). ``extract`` reads the speed off the
    picture ("58KM/H"), as ``extract --ego-speed 58`` gives it, and the focal length from it (the image ego-motion's
    median speed scales with it, as every distance does): the raw scenario's speed before the crash within 10 % of
    the overlay, the focal length ~2.3x the self-calibrated one, and the same crash (ego and the lead car, the same
    frame)."""
    from deepcrashtest.pipeline.extract import run_extract
    from deepcrashtest.scenario import Scenario

    video = need(DATA / "crash_ccd" / "ccd_000014.mp4")
    raws = []
    for name, speed, overlay in (("images", None, False), ("overlay", None, True), ("given", 58.0, True)):
        report = name == "overlay"  # the report says where the speed came from, and plots the readings
        run_extract(video, tmp_path / name, annotate=False, report=report, ego_speed_kmh=speed, overlay=overlay)
        raws.append(Scenario.load(tmp_path / name / "scenario_raw.json"))
    html = (tmp_path / "overlay" / "report.html").read_text()
    assert "the picture&#x27;s GPS overlay: 57-59 km/h, 10 readings" in html
    plain = raws[0]
    assert plain.collision is not None
    plain_t, plain_speed = np.asarray(plain.ego.trajectory.t), np.asarray(plain.ego.trajectory.speed) * 3.6
    assert float(np.median(plain_speed[(plain_t > 0.5) & (plain_t < plain.collision.time_s)])) < 35.0
    for raw, said in zip(raws[1:], ("read off the picture's overlay, 57-59 km/h", "given, 58 km/h"), strict=True):
        crash = raw.collision
        assert crash is not None
        assert {crash.agent_id, crash.other_id} == {plain.collision.agent_id, plain.collision.other_id}
        assert crash.time_s == pytest.approx(plain.collision.time_s)
        t, speed = np.asarray(raw.ego.trajectory.t), np.asarray(raw.ego.trajectory.speed) * 3.6
        before = speed[(t > 0.5) & (t < crash.time_s)]
        assert abs(float(np.median(before)) / 58.0 - 1) < 0.1  # measured 58.3 km/h both (images only: 24.8)
        assert 1.8 < raw.camera.fy / plain.camera.fy < 2.8  # measured 3265 / 1392 px
        notes = raw.provenance.parameters["self_calibration"]["notes"]
        assert any(f"the ego's speed {said}" in n for n in notes), notes


def test_an_ego_speed_given_for_a_standing_ego_is_not_used_and_said(tmp_path):
    """dad_000528's ego stands at a junction (its scene does not grow): a speed given for it cannot scale anything;
    the camera keeps its focal length and the user is told why, in the scenario's warnings."""
    from deepcrashtest.pipeline.extract import run_extract
    from deepcrashtest.scenario import Scenario

    video = need(DAD / "dad_000528.mp4")
    run_extract(video, tmp_path / "out", annotate=False, report=False, max_frames=40, ego_speed_kmh=30.0)
    raw = Scenario.load(tmp_path / "out" / "scenario_raw.json")
    assert raw.camera.fy == pytest.approx(640.0)
    assert any(w.startswith("--ego-speed 30 km/h not used: the video shows the ego standing") for w in raw.warnings)
