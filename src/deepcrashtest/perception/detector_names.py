"""The detectors' names and the ``--detector`` help: light to import (the command line reads them before any
command runs; :mod:`deepcrashtest.perception.detect` and NumPy load only where a detector is built)."""

DEFAULT_DETECTOR = "yolo26n"
DETECTOR_HELP = (
    "yolo26n[:int8,area=PIXELS,size=N,score=S,coarse=N,threads=N,sky=F] (default; YOLO26n weights AGPL-3.0, "
    "Ultralytics; built once by `make models`)"
    " | ssd[:tiles=N,score=S,input=WxH] (SSD-MobileNet-v2, Apache-2.0) | onnx:PATH (any YOLO ONNX)."
)
