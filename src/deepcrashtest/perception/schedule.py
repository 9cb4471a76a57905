"""When the detector runs: every N-th frame, and in video of 24 fps or more fewer calls while nothing changes.

:func:`detect_stable` is :func:`~deepcrashtest.perception.track.detect_ahead`'s schedule (the first frame and
every ``every``-th after it) except that, in video of at least :data:`MIN_SKIP_FPS`, a scheduled call is
skipped when the last two calls agree that the scene is calm (:func:`calm`): they found the same road users
(every box the detector reports, riders joined to their two-wheelers: as many, matched one to one at IoU >=
:data:`STABLE_MIN_IOU`; nothing appeared, left or moved fast between them), no two of them overlap (no road
user passing another or hidden by it) and none is near the ego (a box taller than :data:`NEAR_HEIGHT` of the
image). The call after a skipped one is always made, so calls are never more than ``2 * every`` frames apart.
The schedule depends on the detector's own boxes only, so it still runs in its own thread ahead of the tracker.

Why only from 24 fps: with the same skip rule on every video (branch extractfps6, a fresh extract of the 20
fidelity clips, README Performance, eighth round) a 10 fps CCD clip lost its crash (ccd_000132: calls 0.2 s
apart became 0.4 s, what ``extract.MAX_DETECT_GAP_S`` exists to prevent) and the 20 fps DAD clips' IoU fell (calls
0.25 -> 0.5 s apart). At 25-60 fps, the usual dashcam rates, calls are 0.2 s apart or less, a skip leaves at
most ~0.42 s, and optical flow carries each box over steps of <= 0.042 s. On ``highway_project_video.mp4``
(held out; ``bench/detect_gap.py``, the detector on every frame as the reference) the skip rule of that round
kept the recall of the detector's road users on the frames without a call (0.821 with 50 calls -> 0.827-0.828
with 33-36). The score of the compared boxes is the detector's own threshold (all its boxes): at 0.5 two short
tracks of small, weakly detected oncoming cars on ``highway_lane_challenge.mp4`` were no longer confirmed.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator

import numpy as np

from deepcrashtest.perception.boxes import iou_matrix
from deepcrashtest.perception.detections import Detections, Detector
from deepcrashtest.perception.roadusers import road_users
from deepcrashtest.video.source import Frame

#: Video below this frame rate (frames/s) gets every scheduled call (see the module docstring).
MIN_SKIP_FPS = 24.0
#: Two calls agree when their road users match one to one at least this IoU.
STABLE_MIN_IOU = 0.5
#: A road user whose box is taller than this fraction of the image height is near the ego: no call is skipped
#: (the detector's coarse pass starts there, ``yolo_onnx.COARSE_MIN_HEIGHT``).
NEAR_HEIGHT = 0.2


def _boxes(d: Detections, min_score: float) -> np.ndarray:
    users = road_users(d)
    return np.asarray(users.boxes[users.scores >= min_score], float).reshape(-1, 4)


def same_road_users(a: np.ndarray, b: np.ndarray, min_iou: float = STABLE_MIN_IOU) -> bool:
    """True when two calls' road-user boxes ((n, 4) px) are as many and match one to one at IoU >= ``min_iou``
    (optimal assignment on IoU)."""
    from scipy.optimize import linear_sum_assignment  # loaded in the background while the first frames decode

    if len(a) != len(b):
        return False
    if not len(a):
        return True
    iou = iou_matrix(a, b)
    rows, cols = linear_sum_assignment(-iou)
    return bool((iou[rows, cols] >= min_iou).all())


def calm(a: Detections, b: Detections, height: int, min_iou: float = STABLE_MIN_IOU, min_score: float = 0.0) -> bool:
    """Whether two consecutive calls (on an image ``height`` px tall) leave the next one to skip: the same road
    users (score >= ``min_score``), none overlapping another, none taller than :data:`NEAR_HEIGHT` of the image."""
    ba, bb = _boxes(a, min_score), _boxes(b, min_score)
    if not same_road_users(ba, bb, min_iou):
        return False
    if len(bb) and float((bb[:, 3] - bb[:, 1]).max()) > NEAR_HEIGHT * height:
        return False
    iou = iou_matrix(bb, bb)
    np.fill_diagonal(iou, 0.0)
    return not bool((iou > 0.0).any())


def detect_stable(
    frames: Iterable[Frame],
    detector: Detector,
    every: int = 1,
    fps: float = 0.0,
    min_iou: float = STABLE_MIN_IOU,
    min_score: float = 0.0,
) -> Iterator[tuple[Frame, Detections | None]]:
    """Each frame with the detector's boxes on the frames it runs on (see the module docstring), None between.
    ``fps``: the video's frame rate; below :data:`MIN_SKIP_FPS` every scheduled call is made. ``min_iou``,
    ``min_score``: :func:`calm`'s."""
    if every < 1:
        raise ValueError(f"every must be >= 1 (got {every})")
    skips = fps >= MIN_SKIP_FPS
    last: list[Detections] = []  # the last two calls' boxes
    skipped = False
    for k, frame in enumerate(frames):
        if k % every:
            yield frame, None
            continue
        h = frame.image.shape[0]
        if skips and len(last) == 2 and not skipped and calm(last[0], last[1], h, min_iou, min_score):
            skipped = True
            yield frame, None
            continue
        dets = detector(frame.image)
        last = [*last[-1:], dets]
        skipped = False
        yield frame, dets
