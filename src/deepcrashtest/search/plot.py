"""starts.png: the search's start offsets coloured by outcome, drawn with OpenCV.

Matplotlib took ~1 s of CPU to import for this one figure (a search of 2,000 variants simulates in
about that); OpenCV imports in ~0.2 s and draws it in milliseconds. Frame of the plot: lateral start
offset (m, left positive, drawn on the left) across, longitudinal (m, forward positive) up.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from deepcrashtest.fileio import atomic_path
from deepcrashtest.forking import Helper

# BGR colours (Matplotlib's tab:red, tab:green, gold)
RED, GREEN, GOLD, BLACK, GREY = (40, 39, 214), (44, 160, 44), (0, 215, 255), (0, 0, 0), (128, 128, 128)
W, H = 605, 770  # pixels
AX = (120, 40, 455, 620)  # axes left, top, right, bottom (pixels)
FONT = 0  # cv2.FONT_HERSHEY_SIMPLEX


def preload() -> None:
    """Import OpenCV (the forked output helper does it while the search simulates)."""
    import cv2  # noqa: F401


def start_helper() -> Helper:
    """The search's output helper (``search.run.run_search``'s ``helper``): a forked process that loads OpenCV
    now and later writes results.csv and starts.png. A context manager. This module is light to import, so the
    command line starts it before importing the simulator: the two load side by side on two cores."""
    return Helper(preload)


def plot_starts(
    df: Any, half_box: Any, boundary: dict | None, best: int | None, path: Path, force: bool, title: str
) -> Path:
    """Start offsets (lateral, longitudinal) of every variant, safe green / unsafe red; random variants as
    discs, CEM samples as triangles; the search box dashed, the safe/unsafe boundary (no noise) as a line,
    the original start a cross, the best safe variant a star. Writes a PNG to ``path`` (atomically).

    ``df``: the results table, any mapping of columns (``search.table.Table`` or a pandas DataFrame);
    ``half_box``: the start box's half extents, longitudinal and lateral (m, ``SearchSpace.half_box``)."""
    import cv2

    img = np.full((H, W, 3), 255, np.uint8)
    hb = np.asarray(half_box, float)  # longitudinal, lateral half extents (m)
    lat_lim, lon_lim = 1.15 * hb[1], 1.15 * hb[0]
    # equal aspect: metres per pixel from the tighter axis, the axes box shrunk to fit
    left, top, right, bottom = AX
    scale = min((right - left) / (2 * lat_lim), (bottom - top) / (2 * lon_lim))  # pixels per metre
    cx, cy = (left + right) / 2, (top + bottom) / 2
    left, right = int(cx - lat_lim * scale), int(cx + lat_lim * scale)
    top, bottom = int(cy - lon_lim * scale), int(cy + lon_lim * scale)

    def px(lat: Any, lon: Any) -> np.ndarray:
        """Pixel coordinates (N, 2) of offsets: lateral left positive to the left, forward up."""
        lat, lon = np.atleast_1d(np.asarray(lat, float)), np.atleast_1d(np.asarray(lon, float))
        return np.column_stack([cx - lat * scale, cy - lon * scale]).round().astype(np.int32)

    _dashed_rect(cv2, img, px(hb[1], hb[0])[0], px(-hb[1], -hb[0])[0])
    styles = {"random": ("o", 5), "cem": ("^", 4)}
    legend: list[tuple[str, tuple[int, int, int], str]] = []
    methods, safe = np.asarray(df["method"]), np.asarray(df["safe"], bool)
    lat, lon = np.asarray(df["d_lat"], float), np.asarray(df["d_lon"], float)
    for method, (marker, size) in styles.items():
        for ok, colour, label in ((False, RED, "collision / unsafe"), (True, GREEN, "safe")):
            rows = (methods == method) & (safe == ok)
            if rows.any():
                for p in px(lat[rows], lon[rows]):
                    _marker(cv2, img, p, marker, size, colour)
                legend.append((marker, colour, f"{method}: {label}"))
    if boundary is not None:
        r = np.array([np.nan if v is None else v for v in boundary["radius_m"]], dtype=float)
        a = np.radians(boundary["angle_deg"])
        r, a = np.append(r, r[:1]), np.append(a, a[:1])
        pts = px(np.nan_to_num(r * np.sin(a)), np.nan_to_num(r * np.cos(a)))
        ok = np.isfinite(r)
        for i in np.flatnonzero(ok[:-1] & ok[1:]):  # a ray without a boundary breaks the line
            cv2.line(img, tuple(map(int, pts[i])), tuple(map(int, pts[i + 1])), BLACK, 1, cv2.LINE_AA)
        legend.append(("-", BLACK, "safe/unsafe boundary (no noise)"))
    _marker(cv2, img, px(0.0, 0.0)[0], "x", 7, BLACK)
    legend.append(("x", BLACK, "original start"))
    if best is not None:
        b = int(np.flatnonzero(np.asarray(df["variant"]) == best)[0])
        _marker(cv2, img, px(lat[b], lon[b])[0], "*", 12, GOLD)
        legend.append(("*", GOLD, "best safe"))
    _axes(cv2, img, (left, top, right, bottom), lat_lim, lon_lim, px)
    _text(cv2, img, title, (W // 2, 22), 0.45, centre=True)
    _legend(cv2, img, legend, bottom + 58)
    ok, png = cv2.imencode(".png", img)
    if not ok:
        raise OSError(f"could not encode {path}")
    with atomic_path(path, force=force) as tmp:
        Path(tmp).write_bytes(png.tobytes())
    return path


def _text(cv2: Any, img: np.ndarray, s: str, at: tuple[int, int], size: float = 0.42, centre: bool = False) -> None:
    (w, h), _ = cv2.getTextSize(s, FONT, size, 1)
    x = at[0] - w // 2 if centre else at[0]
    cv2.putText(img, s, (int(x), int(at[1] + h // 2)), FONT, size, BLACK, 1, cv2.LINE_AA)


def _marker(cv2: Any, img: np.ndarray, p: np.ndarray, kind: str, size: int, colour: tuple[int, int, int]) -> None:
    x, y = int(p[0]), int(p[1])
    if kind == "o":
        cv2.circle(img, (x, y), size, colour, -1, cv2.LINE_AA)
    elif kind == "^":
        tri = np.array([[x, y - size], [x - size, y + size], [x + size, y + size]], np.int32)
        cv2.fillPoly(img, [tri], colour, cv2.LINE_AA)
    elif kind == "x":
        cv2.line(img, (x - size, y - size), (x + size, y + size), colour, 2, cv2.LINE_AA)
        cv2.line(img, (x - size, y + size), (x + size, y - size), colour, 2, cv2.LINE_AA)
    elif kind == "*":
        a = np.pi / 2 + np.arange(10) * np.pi / 5
        r = np.where(np.arange(10) % 2 == 0, size, 0.42 * size)
        star = np.column_stack([x + r * np.cos(a), y - r * np.sin(a)]).round().astype(np.int32)
        cv2.fillPoly(img, [star], colour, cv2.LINE_AA)
        cv2.polylines(img, [star], True, BLACK, 1, cv2.LINE_AA)
    else:  # a line sample (legend)
        cv2.line(img, (x - size, y), (x + size, y), colour, 1, cv2.LINE_AA)


def _dashed_rect(cv2: Any, img: np.ndarray, p0: np.ndarray, p1: np.ndarray, dash: int = 6) -> None:
    (x0, y0), (x1, y1) = p0, p1
    for a, b in (((x0, y0), (x1, y0)), ((x1, y0), (x1, y1)), ((x1, y1), (x0, y1)), ((x0, y1), (x0, y0))):
        n = max(1, int(np.hypot(b[0] - a[0], b[1] - a[1]) // dash))
        t = np.linspace(0.0, 1.0, n + 1)
        pts = np.column_stack([a[0] + (b[0] - a[0]) * t, a[1] + (b[1] - a[1]) * t]).round().astype(int)
        for i in range(0, n, 2):
            cv2.line(img, tuple(map(int, pts[i])), tuple(map(int, pts[i + 1])), GREY, 1, cv2.LINE_AA)


def _ticks(lim: float) -> np.ndarray:
    step = 1.0 if lim <= 3.0 else 2.0 if lim <= 6.0 else 5.0
    k = np.floor(lim / step)
    return np.arange(-k, k + 1) * step


def _axes(cv2: Any, img: np.ndarray, box: tuple[int, int, int, int], lat_lim: float, lon_lim: float, px: Any) -> None:
    left, top, right, bottom = box
    cv2.rectangle(img, (left, top), (right, bottom), BLACK, 1)
    for v in _ticks(lat_lim):
        x = int(px(v, 0.0)[0, 0])
        cv2.line(img, (x, bottom), (x, bottom + 5), BLACK, 1)
        _text(cv2, img, f"{v:g}", (x, bottom + 16), centre=True)
    for v in _ticks(lon_lim):
        y = int(px(0.0, v)[0, 1])
        cv2.line(img, (left - 5, y), (left, y), BLACK, 1)
        label = f"{v:g}"
        (w, _), _ = cv2.getTextSize(label, FONT, 0.42, 1)
        _text(cv2, img, label, (left - 9 - w, y))
    _text(cv2, img, "lateral start offset (m, left +)", ((left + right) // 2, bottom + 38), centre=True)
    # the vertical label: drawn on its own strip, turned a quarter anticlockwise
    label = "longitudinal start offset (m, forward +)"
    (w, h), _ = cv2.getTextSize(label, FONT, 0.42, 1)
    strip = np.full((h + 10, w + 10, 3), 255, np.uint8)
    cv2.putText(strip, label, (5, h + 4), FONT, 0.42, BLACK, 1, cv2.LINE_AA)
    strip = cv2.rotate(strip, cv2.ROTATE_90_COUNTERCLOCKWISE)
    y0 = max(0, (top + bottom) // 2 - strip.shape[0] // 2)
    x0 = max(0, left - 52 - strip.shape[1])
    sub = img[y0 : y0 + strip.shape[0], x0 : x0 + strip.shape[1]]
    np.minimum(sub, strip[: sub.shape[0], : sub.shape[1]], out=sub)


def _legend(cv2: Any, img: np.ndarray, items: list[tuple[str, tuple[int, int, int], str]], top: int) -> None:
    """Two columns of (marker, label) below the axes, in a thin frame."""
    if not items:
        return
    rows = (len(items) + 1) // 2
    x0, x1 = 70, W - 70
    cv2.rectangle(img, (x0, top), (x1, top + 10 + 18 * rows), (200, 200, 200), 1)
    col_w = (x1 - x0) // 2
    for n, (kind, colour, label) in enumerate(items):
        col, row = n // rows, n % rows
        x, y = x0 + 16 + col * col_w, top + 14 + 18 * row
        _marker(cv2, img, np.array([x, y]), kind, 5 if kind not in "*x" else 7, colour)
        _text(cv2, img, label, (x + 14, y), 0.36)
