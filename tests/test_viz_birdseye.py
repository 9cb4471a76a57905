"""The bird's-eye video's tags: each road user's id written where no other tag is, on a real crowd (KITTI 0017's
pedestrians from its labels, replayed)."""

from __future__ import annotations

import cv2
import pytest

from conftest import KITTI_TRACKING, need
from deepcrashtest.viz import birdseye

pytestmark = pytest.mark.filterwarnings("ignore::DeprecationWarning")


def _text_box(org: tuple[int, int], text: str) -> tuple[int, int, int, int]:
    (w, h), base = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, birdseye.TAG_SCALE, 1)
    return org[0], org[1] - h, org[0] + w, org[1] + base


def _overlapping(boxes: list[tuple[int, int, int, int]]) -> int:
    return sum(birdseye._meet(boxes[i], boxes[j]) for i in range(len(boxes)) for j in range(i))


def test_a_crowds_tags_do_not_cover_each_other(monkeypatch):
    """KITTI 0017 (a dozen pedestrians on a pavement, from its labels): in every drawn frame no two tags overlap,
    where one tag above each road user (the layout before) overlapped in every frame."""
    need(KITTI_TRACKING)
    from deepcrashtest.datasets.kitti.scenario import scenario_from_kitti
    from deepcrashtest.sim import simulate

    sc = scenario_from_kitti(KITTI_TRACKING, 17, road_users=True)
    res = simulate(sc, controller="replay")
    seen: list[tuple[list[tuple[int, int]], list[str], list[tuple[tuple[int, int], bool]]]] = []
    place = birdseye.place_tags

    def recorded(anchors, texts, shapes=None):
        out = place(anchors, texts, shapes)
        seen.append((anchors, texts, out))
        return out

    monkeypatch.setattr(birdseye, "place_tags", recorded)
    frames = sum(1 for _ in birdseye.render_frames(sc, res, stride=10))
    assert len(seen) == frames > 50
    above = [
        _overlapping([_text_box((x - 6, y - 14), t) for (x, y), t in zip(a, tx, strict=True)]) for a, tx, _ in seen
    ]
    placed = [_overlapping([_text_box(org, t) for (org, _), t in zip(out, tx, strict=True)]) for _, tx, out in seen]
    assert min(above) > 0  # measured: 73 of 73 frames
    assert max(placed) == 0
