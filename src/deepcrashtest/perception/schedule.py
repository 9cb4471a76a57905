"""When the detector runs: every N-th frame, or fewer calls while the road users stay as they were.

:func:`detect_stable` is :func:`~deepcrashtest.perception.track.detect_ahead`'s schedule (the first frame and
every ``every``-th after it) except that a scheduled call is skipped when the last two calls found the same
road users: as many (score >= ``STABLE_MIN_SCORE``, riders joined to their two-wheelers), matched one to one
at IoU >= ``min_iou`` (nothing appeared, left, or moved fast between them), and the call before was not
skipped (so two calls are never more than ``2 * every`` frames apart). The schedule depends on the
detector's own boxes only, so it still runs in its own thread ahead of the tracker.

Measured with ``bench/detect_gap.py --every 5,6 --stable-iou 0.3,0.5,0.7`` (the detector on every frame as
the reference; recall of its road users by the tracker's boxes on the frames without a call, IoU >= 0.5):
``highway_lane_challenge.mp4`` (tuning), 250 frames: every 5th 0.935 with 50 calls, skipped when stable 0.922
with 36 calls; ``highway_project_video.mp4`` (held out): 0.821 with 50 calls against 0.828 with 33 (mean IoU
0.910 -> 0.896), where a fixed every 6th frame gave 0.765 with 42. The IoU threshold made no difference there
(0.3-0.7: the counts decide); 0.5 is the tracker's own match level of the benchmark.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator

import numpy as np

from deepcrashtest.perception.boxes import iou_matrix
from deepcrashtest.perception.detections import Detections, Detector
from deepcrashtest.perception.roadusers import road_users
from deepcrashtest.video.source import Frame

#: Road users scoring below this do not count in the comparison of two calls (the tracker's ``new_track_score``).
STABLE_MIN_SCORE = 0.5
#: Two calls agree when their road users match one to one at least this IoU.
STABLE_MIN_IOU = 0.5


def same_road_users(a: Detections, b: Detections, min_iou: float = STABLE_MIN_IOU) -> bool:
    """True when two calls' road users (score >= ``STABLE_MIN_SCORE``) are as many and match one to one at IoU
    >= ``min_iou`` (optimal assignment on IoU)."""
    from scipy.optimize import linear_sum_assignment  # loaded in the background while the first frames decode

    boxes = []
    for d in (a, b):
        users = road_users(d)
        boxes.append(np.asarray(users.boxes[users.scores >= STABLE_MIN_SCORE], float).reshape(-1, 4))
    if len(boxes[0]) != len(boxes[1]):
        return False
    if not len(boxes[0]):
        return True
    iou = iou_matrix(boxes[0], boxes[1])
    rows, cols = linear_sum_assignment(-iou)
    return bool((iou[rows, cols] >= min_iou).all())


def detect_stable(
    frames: Iterable[Frame], detector: Detector, every: int = 1, min_iou: float = STABLE_MIN_IOU
) -> Iterator[tuple[Frame, Detections | None]]:
    """Each frame with the detector's boxes on the frames it runs on (see the module docstring), None between."""
    if every < 1:
        raise ValueError(f"every must be >= 1 (got {every})")
    last: list[Detections] = []  # the last two calls' boxes
    skipped = False
    for k, frame in enumerate(frames):
        if k % every:
            yield frame, None
            continue
        if len(last) == 2 and not skipped and same_road_users(last[0], last[1], min_iou):
            skipped = True
            yield frame, None
            continue
        dets = detector(frame.image)
        last = [*last[-1:], dets]
        skipped = False
        yield frame, dets
