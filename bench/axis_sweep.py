"""Forward-axis column (``cx``) of the self-calibrated camera: estimate, sigma and fusion, training sequences only.

    PYTHONPATH=src nice -n 10 python bench/axis_sweep.py --cache DIR [--sequences 0,1,2] [--variants]

Per sequence: the path estimate of :func:`~deepcrashtest.geometry.selfcalib_axis.axis_column_from_path`
(column, bootstrap sigma, tracks; counted from 3 tracks up so that the track floor can be swept), the KITTI
column and the MOTA with the unknown camera at the image centre, at the true column and at the estimate.
Then the combined MOTA (summed FN, FP, IDSW over summed ground truth) of the inverse-variance fusion with the
image-centre prior for a grid of sigma models ``hypot(k sigma_boot, floor)`` and track floors. ``--variants``
also prints the estimate's error with relaxed row and depth limits. Default: the 18 training sequences other
than 3, 8, 10 (never the held-out ones). ``--cache``: the image tracks (the same files as
``bench/selfcalib_diag.py --cache``; use a fresh folder, old ones hold stale tracks).
"""

from __future__ import annotations

import argparse
import itertools
import math
from pathlib import Path

from selfcalib_diag import _combined, _mota, load_sequence, training_args

from deepcrashtest.geometry import selfcalib as sc
from deepcrashtest.geometry import selfcalib_axis as ax

GRID_K = (1.0, 2.0, 3.0, 4.0, 5.0, 6.0)
GRID_FLOOR = (0.0, 3.0, 5.0, 8.0)
GRID_TRACKS = (3, 5, 10)


def _estimate(boxes, cam, ego) -> tuple[float, float, int] | None:
    """The path estimate run twice (the second from the first's column), as ``_calibrate_axis`` does."""
    est = ax.axis_column_from_path(boxes, cam.fy, cam.cx, ego, sc.BOX_HEIGHT_EXCESS)
    if est is not None:
        est = ax.axis_column_from_path(boxes, cam.fy, est[0], ego, sc.BOX_HEIGHT_EXCESS)
    return est


def _post(d: dict, k: float, floor: float, min_tracks: int) -> float:
    """Inverse-variance fusion of the estimate (sigma ``hypot(k boot, floor)``) with the image-centre prior."""
    cam, est = d["cam"], d["est"]
    if est is None or est[2] < min_tracks:
        return float(cam.cx)
    sig = max(math.hypot(k * est[1], floor), 1e-3)
    w, w0 = 1.0 / sig**2, 1.0 / (sc.AXIS_PRIOR_REL * d["size"][0]) ** 2
    return (w * est[0] + w0 * cam.cx) / (w + w0)


def _load(seqs: list[int], cache: Path) -> dict[int, dict]:
    """Per sequence: the camera self-calibrated up to (not including) the axis step, the estimate, the truth."""
    keep = sc._calibrate_axis
    sc._calibrate_axis = lambda tracks, size, cam, ego, notes: cam  # the camera before the axis step
    ax.MIN_TRACKS = min(GRID_TRACKS)
    data = {}
    try:
        for s in seqs:
            prep, tracks, ego, start = load_sequence(s, cache)
            cam = sc.self_calibrate(tracks, start, prep.size, ego).camera
            boxes = sc._usable(tracks, prep.size)
            data[s] = {
                "prep": prep, "tracks": tracks, "cam": cam, "size": prep.size, "true": prep.camera.cx,
                "est": _estimate(boxes, cam, ego), "boxes": boxes, "ego": ego,
            }  # fmt: skip
    finally:
        sc._calibrate_axis = keep
    return data


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--variants", action="store_true")
    args, seqs, cache = training_args(ap, None)
    data = _load(seqs, cache)
    memo: dict[tuple[int, float], dict] = {}

    def res(s: int, cx: float) -> dict:
        key = (s, round(cx * 2.0) / 2.0)
        if key not in memo:
            d = data[s]
            memo[key] = _mota(d["prep"], d["tracks"], d["cam"].model_copy(update={"cx": key[1]}))[1]
        return memo[key]

    for s, d in data.items():
        e, c, t = d["est"], float(d["cam"].cx), d["true"]
        m_c, m_t = (100 * float(res(s, x)["MOTA"]) for x in (c, t))
        line = f"{s:04d} true {t:.1f} centre {c:.1f}:{m_c:.2f} at true {m_t:.2f}"
        if e is not None:
            m_e = 100 * float(res(s, e[0])["MOTA"])
            line += f" | est {e[0]:.1f} +-{e[1]:.1f} ({e[2]} tracks) err {e[0] - t:+.1f}: {m_e:.2f}"
        print(line, flush=True)
    print(f"combined: centre {_combined([res(s, float(d['cam'].cx)) for s, d in data.items()]):.2f} "
          f"true {_combined([res(s, d['true']) for s, d in data.items()]):.2f}")  # fmt: skip
    for k, floor, n in itertools.product(GRID_K, GRID_FLOOR, GRID_TRACKS):
        m = _combined([res(s, _post(d, k, floor, n)) for s, d in data.items()])
        print(f"sigma hypot({k:g} boot, {floor:g}) tracks >= {n}: combined {m:.2f}", flush=True)
    if args.variants:
        for name, value in (("MIN_ROWS", 5), ("MAX_DEPTH_M", 60.0)):
            keep = getattr(ax, name)
            setattr(ax, name, value)
            errs = {s: _estimate(d["boxes"], d["cam"], d["ego"]) for s, d in data.items()}
            setattr(ax, name, keep)
            print(f"{name}={value}: " + " ".join(
                f"{s}:{e[0] - data[s]['true']:+.1f}({e[2]})" for s, e in errs.items() if e is not None
            ))  # fmt: skip


if __name__ == "__main__":
    main()
