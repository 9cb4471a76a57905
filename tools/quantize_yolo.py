"""One-time int8 quantization of the exported YOLO26n ONNX model (run in the export venv, ``make models``).

Static quantization with onnxruntime.quantization: QDQ format, int8 weights per output channel, uint8
activations, MinMax ranges calibrated on a FIXED set of training frames only (never the detector or fidelity
evaluation data: KITTI tracking, the KITTI raw highway queue, the CCD/DAD crash clips, highway_lane_challenge):

* every 25th frame of ``dashcam_udacity/highway_solid_white_right.mp4`` (960x540 colour dashcam),
* every 16th frame of KITTI odometry ``seq00`` (grey camera, as BGR),

each letterboxed exactly as the detector does (its 864x480-class input and its 320 px coarse pass). The
detection head (``/model.23/``: box decoding, class scores) stays float. Deterministic: fixed frames, fixed
order, MinMax (no sampling). Weights licence: AGPL-3.0 (Ultralytics), as the float model's.

Usage: PYTHONPATH=src python tools/quantize_yolo.py FLOAT.onnx OUT.onnx --data ../shared/data
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import cv2
import numpy as np

#: The detector's coarse pass long side (px), as ``perception.detect.YOLO_COARSE``.
COARSE = 320


def calibration_frames(data: Path) -> list[np.ndarray]:
    """The fixed calibration frames (BGR), in a fixed order."""
    frames: list[np.ndarray] = []
    cap = cv2.VideoCapture(str(data / "dashcam_udacity" / "highway_solid_white_right.mp4"))
    k = 0
    while True:
        ok, img = cap.read()
        if not ok:
            break
        if k % 25 == 12:
            frames.append(img)
        k += 1
    cap.release()
    seq = sorted((data / "kitti_odometry" / "seq00_frames0000-0159" / "image_0").glob("*.png"))
    frames += [cv2.cvtColor(cv2.imread(str(p), cv2.IMREAD_GRAYSCALE), cv2.COLOR_GRAY2BGR) for p in seq[8::16]]
    if len(frames) < 10:
        raise SystemExit(f"too few calibration frames under {data} ({len(frames)})")
    return frames


def blobs(model: Path, frames: list[np.ndarray]) -> list[np.ndarray]:
    """The detector's own inputs for each frame: the main pass and the coarse pass."""
    from deepcrashtest.perception.yolo_onnx import OnnxYoloDetector

    det = OnnxYoloDetector(model, masks=False)
    out = []
    for img in frames:
        h, w = img.shape[:2]
        out.append(det._letterbox(img, det.input_size(h, w))[0])
        det.long_side = COARSE
        out.append(det._letterbox(img, det.input_size(h, w))[0])
        det.long_side = None
    return out


class Reader:
    """onnxruntime's calibration data reader over a list of input blobs."""

    def __init__(self, name: str, inputs: list[np.ndarray]) -> None:
        self.name, self.items = name, iter(inputs)

    def get_next(self) -> dict[str, np.ndarray] | None:
        item = next(self.items, None)
        return None if item is None else {self.name: item}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("model", type=Path, help="the float YOLO26n ONNX (tools/export_yolo.py)")
    ap.add_argument("out", type=Path)
    ap.add_argument("--data", type=Path, required=True, help="the shared data folder")
    ap.add_argument("--reduce-range", action="store_true", help="7-bit weights (no u8s8 saturation on AVX2)")
    args = ap.parse_args()
    import onnx
    from onnxruntime.quantization import CalibrationMethod, QuantFormat, QuantType, quantize_static
    from onnxruntime.quantization.shape_inference import quant_pre_process

    inputs = blobs(args.model, calibration_frames(args.data))
    graph = onnx.load(str(args.model)).graph
    head = [n.name for n in graph.node if n.name.startswith("/model.23/")]
    with tempfile.TemporaryDirectory() as tmp:
        pre = Path(tmp) / "pre.onnx"
        quant_pre_process(str(args.model), str(pre), skip_symbolic_shape=True)
        part = args.out.with_suffix(".part")
        quantize_static(
            str(pre),
            str(part),
            Reader(graph.input[0].name, inputs),
            quant_format=QuantFormat.QDQ,
            per_channel=True,
            weight_type=QuantType.QInt8,
            activation_type=QuantType.QUInt8,
            calibrate_method=CalibrationMethod.MinMax,
            nodes_to_exclude=head,
            reduce_range=args.reduce_range,
        )
        part.replace(args.out)
    print(f"wrote {args.out} ({len(inputs)} calibration inputs, {len(head)} head nodes float)")


if __name__ == "__main__":
    main()
