"""Text burned into a video's picture (a dashcam's date, GPS and speed line), read by a text reader (OCR).

One interface, :class:`TextReader` (image in, :class:`TextLine` out), so another reader can be plugged in.
The one shipped, :class:`RapidOcrReader`, runs PaddleOCR's PP-OCRv4 detection and recognition models through
onnxruntime, from the PyPI wheel ``rapidocr_onnxruntime`` (the weights are inside the wheel; nothing is
downloaded). ``make setup`` installs it with ``--no-deps`` (it asks for the GUI ``opencv-python``, which clashes
with the headless build; FACTS.md); :func:`make_text_reader` returns None where it is not installed.
"""

from __future__ import annotations

import importlib.util
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

#: A gap between two glyphs wider than this fraction of the glyph before it starts a new word: a dashcam's
#: overlay fields ("044.880800 034.992400 58KM/H") are read as one line, and a speed's digits must not take the
#: GPS coordinate's last digits before them.
WORD_GAP = 0.6


@dataclass(frozen=True)
class TextLine:
    """One line of text: ``box`` (x1, y1, x2, y2 px in the image read), ``text`` (words separated by one space
    where the glyphs leave a gap), ``score`` (the reader's confidence, 0-1) and ``words`` (each word's x1, x2 px;
    empty where the reader does not place its glyphs)."""

    box: tuple[int, int, int, int]
    text: str
    score: float
    words: tuple[tuple[int, int], ...] = ()


class TextReader(Protocol):
    """Finds and reads lines of text in a BGR uint8 image."""

    def detect(self, image: np.ndarray) -> int:
        """How many lines of text ``image`` holds, without reading them (cheap: whether :meth:`find` is worth it)."""
        ...

    def find(self, image: np.ndarray) -> list[TextLine]:
        """Every line of text found in ``image`` (boxes in its pixels)."""
        ...

    def read(self, image: np.ndarray) -> tuple[str, float]:
        """The text of ``image``, a crop holding one line, and the reader's confidence (0-1)."""
        ...


def make_text_reader(name: str = "rapidocr") -> TextReader | None:
    """The text reader ``name`` (``rapidocr``; ``none``: no reader), or None where its package is not installed."""
    if name == "none" or importlib.util.find_spec("rapidocr_onnxruntime") is None:
        return None
    if name != "rapidocr":
        raise ValueError(f"unknown text reader {name!r}")
    return RapidOcrReader()


class RapidOcrReader:
    """PP-OCRv4 detection + recognition (``rapidocr_onnxruntime`` 1.4) on one onnxruntime thread each.

    Detection runs at the image's own size (up to ``max_side`` px, never enlarged): the overlay's glyphs, 15-30 px
    tall in a 720p frame, are the size the models were trained on. No orientation classifier: burned-in text is
    upright. The models load on first use: :meth:`detect` the detection model alone (~30 MB, ~15 ms for a 640 x 60
    px band), :meth:`find` and :meth:`read` all of them (~120 MB)."""

    def __init__(self, max_side: int = 1280, threads: int = 1) -> None:
        self.max_side = max_side
        self.threads = threads
        self._ocr: Any = None
        self._det: Any = None

    def _options(self) -> dict[str, Any]:
        return {"intra_op_num_threads": self.threads, "inter_op_num_threads": self.threads}

    def detect(self, image: np.ndarray) -> int:
        if self._det is None:
            from rapidocr_onnxruntime.ch_ppocr_det import TextDetector
            from rapidocr_onnxruntime.main import DEFAULT_CFG_PATH
            from rapidocr_onnxruntime.utils import read_yaml
            from rapidocr_onnxruntime.utils.parse_parameters import update_model_path

            config = update_model_path(read_yaml(DEFAULT_CFG_PATH))["Det"]
            config |= self._options() | {"limit_type": "max", "limit_side_len": self.max_side}
            self._det = TextDetector(config)
        boxes, _ = self._det(image)
        return 0 if boxes is None else len(boxes)

    def _reader(self) -> Any:
        if self._ocr is None:
            from rapidocr_onnxruntime import RapidOCR

            self._ocr = RapidOCR(
                **self._options(),
                det_limit_type="max",
                det_limit_side_len=self.max_side,
                use_cls=False,
                print_verbose=False,
            )
        return self._ocr

    def find(self, image: np.ndarray) -> list[TextLine]:
        found, _ = self._reader()(image, use_cls=False, return_word_box=True)
        return [_line(item) for item in found or []]

    def read(self, image: np.ndarray) -> tuple[str, float]:
        found, _ = self._reader()(image, use_det=False, use_cls=False, use_rec=True)
        if not found:
            return "", 0.0
        text, score = found[0][0], found[0][1]
        return str(text), float(score)


def _line(item: list[Any]) -> TextLine:
    """A :class:`TextLine` from one of RapidOCR's results ``[quad, text, score(, glyph quads)]``."""
    quad = np.asarray(item[0], dtype=float)
    box = (int(quad[:, 0].min()), int(quad[:, 1].min()), int(np.ceil(quad[:, 0].max())), int(np.ceil(quad[:, 1].max())))
    text, score = str(item[1]), float(item[2])
    glyphs = item[3] if len(item) > 3 and item[3] is not None else []
    if len(glyphs) != len(text):  # the reader did not place every glyph: the words as it wrote them
        return TextLine(box, text, score)
    words, spans = _words(text, [(float(g[0][0]), float(g[1][0])) for g in glyphs])
    return TextLine(box, " ".join(words), score, tuple(spans))


def _words(text: str, glyph_x: list[tuple[float, float]]) -> tuple[list[str], list[tuple[int, int]]]:
    """``text`` split into words where the glyphs (each x1, x2 px) leave a gap wider than :data:`WORD_GAP`
    glyphs, and each word's x1, x2 (px)."""
    words: list[str] = []
    spans: list[tuple[int, int]] = []
    for ch, (x1, x2) in zip(text, glyph_x, strict=True):
        if ch.isspace():
            continue
        if spans and x1 - spans[-1][1] <= WORD_GAP * max(x2 - x1, 1.0):
            words[-1] += ch
            spans[-1] = (spans[-1][0], int(round(x2)))
        else:
            words.append(ch)
            spans.append((int(round(x1)), int(round(x2))))
    return words, spans
