"""Crash fidelity on the labelled crash clips changed as other dashcams would film them: is the crash still made?

The pipeline was developed on the 19 labelled crash clips, so their own fidelity table (``bench/fidelity_crashes.py``)
flatters it. Here each clip is first rewritten as a clip the project has not seen, with its labels moved along,
then extracted and replayed exactly like ``bench/fidelity_crashes.py``:

* ``mirror``: left and right swapped (traffic on the other side of the road; label boxes mirrored);
* ``small``: scaled to 854x480 (label boxes scaled);
* ``halffps``: every second frame (DAD 20 -> 10 fps, CCD 10 -> 5 fps; contact frames halved);
* ``large``: scaled up to 1920x1080, the size most dashcams record (label boxes scaled; not in the default set);
* ``tiny``: scaled down to 426x240, an old upload's size (label boxes scaled; not in the default set);
* ``fisheye``: the barrel distortion of a wide-angle dashcam lens added (radial, the frame's corners kept in the
  frame, the centre magnified ``1 + FISHEYE_K``; label boxes: the bounding box of each box's distorted outline;
  not in the default set);
* ``zoom``: the middle ``1 / ZOOM`` of the frame scaled back up to the frame's size, a narrower lens (a longer
  focal length; label boxes scaled and clipped; not in the default set);
* ``portrait``: the frame scaled to 720 px wide inside a 720x1280 portrait frame, black bars above and below (a
  dashcam clip played on a phone held upright and screen-recorded, as social media carry them; label boxes scaled
  and moved down; not in the default set);
* ``dark``: a dusk / low-light copy: every pixel's brightness x ``DARK_GAIN``, seeded Gaussian sensor noise of
  ``DARK_NOISE`` grey levels added (labels unchanged; not in the default set);
* ``wiper``: filmed through a windscreen in the rain: two wiper blades (dark, out of focus, ``WIPER_WIDTH`` of the
  frame's width wide) pivoting below the frame's bottom sweep up across the view and back every ``WIPER_PERIOD_S``
  (labels unchanged; not in the default set);
* ``late``: the clip starts ``LATE_LEAD_S`` before the labelled contact (a clip cut from a longer recording or a
  compilation's shot that begins shortly before the crash: little footage to calibrate on and short tracks; a clip
  without a contact loses its first half; label frames moved along; not in the default set);
* ``end``: the clip ends ``END_TAIL_S`` after the labelled contact (a compilation's shot cut right after the impact:
  little or no aftermath, no shaking or stopping after it to see; clips already ending sooner and clips without a
  contact keep their end; labels unchanged; not in the default set);
* ``shot``: ``late`` and ``end`` together: ``LATE_LEAD_S`` before the contact to ``END_TAIL_S`` after it (a
  compilation's shot of the crash alone, ~2 s; not in the default set);
* ``copy``: only re-encoded, the control: what the re-encoding alone changes.

Clips are written by the project's own H.264 writer (CRF 23, ultrafast): PyAV's default x264 preset fed ``bgr24``
frames 854 px wide gave different bytes from run to run.

Where ``bench/robust_variants.py`` makes many realistic variants of a few clips (phone-filmed, compilations, ...),
this makes a few plain variants of every labelled clip and prints one line per variant.

Usage::

    python bench/fidelity_perturbed.py
        [--variants mirror,small,halffps,copy,large,tiny,fisheye,zoom,portrait,dark,wiper] [--clips a,b]
        [--work DIR] [--reuse] [--stage2 [--redetect]] [--json]

Per variant: reproduced crashes / labelled, clips with a contact before the crash, mean reprojection IoU
(processed / replay), and the clips not reproduced with their first replay contact. ``--reuse`` keeps the
rewritten clips and extraction outputs already in ``--work``; ``--stage2`` reruns stage 2 only (a stage-2 or
simulator change). Extraction takes ~2-4 min per variant on 2 cores (a 5 s clip each).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path
from typing import Any

import numpy as np
from fidelity_crashes import DATA, all_labels, run_clip

VARIANTS = ("mirror", "small", "halffps", "copy")
#: Variants run only when asked for (``--variants large``).
MORE_VARIANTS = ("large", "tiny", "fisheye", "zoom", "portrait", "dark", "wiper", "late", "end", "shot")
#: ``fisheye``: source radius = r (1 + k r^2) / (1 + k), r the output pixel's distance from the centre over the
#: half diagonal: the corners stay, the centre is magnified 1 + k, straight lines bow outwards (barrel).
FISHEYE_K = 0.35
#: ``zoom``: the focal length's factor (the middle 1/ZOOM of the width and height kept).
ZOOM = 1.3
SMALL_WIDTH, SMALL_HEIGHT = 854, 480
LARGE_WIDTH, LARGE_HEIGHT = 1920, 1080
TINY_WIDTH, TINY_HEIGHT = 426, 240
PORTRAIT_WIDTH, PORTRAIT_HEIGHT = 720, 1280
#: ``dark``: the brightness factor and the sensor noise's sigma (grey levels, 0-255).
DARK_GAIN, DARK_NOISE = 0.3, 3.0
#: ``wiper``: one sweep up and back (s; ~45 wipes a minute, a wiper's low speed), the blade's width (share of the
#: frame's width, blurred: the camera focuses on the road), its opacity, and the pivots (shares of the frame's
#: width and height, below its bottom) with the blades' length (share of the frame's height).
WIPER_PERIOD_S = 1.3
WIPER_WIDTH = 0.035
WIPER_OPACITY = 0.9
WIPER_PIVOTS = ((0.12, 1.2), (0.62, 1.2))
WIPER_LENGTH = 1.15
#: ``late``: the footage kept before the labelled contact (s).
LATE_LEAD_S = 1.5
#: ``end``: the footage kept after the labelled contact (s).
END_TAIL_S = 0.3


def variant_geometry(src: Path, variant: str) -> tuple[float, int, tuple[float, float], int]:
    """What ``variant`` does to the frames of ``src``: (new fps, frame step, box scale x and y, source width)."""
    import av

    with av.open(str(src)) as inp:
        stream = inp.streams.video[0]
        fps, width, height = float(stream.average_rate), int(stream.width), int(stream.height)
    step = 2 if variant == "halffps" else 1
    sizes = {"small": (SMALL_WIDTH, SMALL_HEIGHT), "large": (LARGE_WIDTH, LARGE_HEIGHT)}
    sizes["tiny"] = (TINY_WIDTH, TINY_HEIGHT)
    size = sizes.get(variant, (width, height))
    scale = (size[0] / width, size[1] / height)
    return fps / step, step, scale, width


def late_start(label: dict[str, Any], frames: int) -> int:
    """The first frame the ``late`` variant keeps of a clip of ``frames`` frames labelled ``label``."""
    contact = label.get("contact_frame")
    if contact is None:
        return frames // 2
    return max(0, int(contact) - round(LATE_LEAD_S * float(label["fps"])))


def end_stop(label: dict[str, Any], frames: int) -> int:
    """The frame after the last one the ``end`` variant keeps of a clip of ``frames`` frames labelled ``label``."""
    contact = label.get("contact_frame")
    if contact is None:
        return frames
    return min(frames, int(contact) + round(END_TAIL_S * float(label["fps"])) + 1)


def rewrite_clip(src: Path, dst: Path, variant: str, start: int = 0, stop: int | None = None) -> None:
    """Write ``src`` changed by ``variant`` (:func:`variant_geometry`) to ``dst``, its frames ``start`` to ``stop``
    (exclusive; None: to the end)."""
    import av
    import cv2

    from deepcrashtest.video.writer import VideoWriter

    fps, step, _scale, _width = variant_geometry(src, variant)
    with av.open(str(src)) as inp:
        frames = [f.to_ndarray(format="bgr24") for f in inp.decode(inp.streams.video[0])]
    if variant == "mirror":
        frames = [cv2.flip(f, 1) for f in frames]
    elif variant == "small":
        frames = [cv2.resize(f, (SMALL_WIDTH, SMALL_HEIGHT), interpolation=cv2.INTER_AREA) for f in frames]
    elif variant == "tiny":
        frames = [cv2.resize(f, (TINY_WIDTH, TINY_HEIGHT), interpolation=cv2.INTER_AREA) for f in frames]
    elif variant == "large":
        frames = [cv2.resize(f, (LARGE_WIDTH, LARGE_HEIGHT), interpolation=cv2.INTER_CUBIC) for f in frames]
    elif variant == "portrait":
        frames = [_portrait(f) for f in frames]
    elif variant == "dark":
        rng = np.random.default_rng(0)
        frames = [
            np.clip(f * DARK_GAIN + rng.normal(0.0, DARK_NOISE, f.shape), 0, 255).astype(np.uint8) for f in frames
        ]
    elif variant == "wiper":
        frames = [wiped(f, k / fps) for k, f in enumerate(frames)]
    elif variant in ("fisheye", "zoom"):
        h, w = frames[0].shape[:2]
        map_x, map_y = lens_maps(w, h, variant)
        frames = [cv2.remap(f, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE) for f in frames]
    frames = frames[start:stop:step]
    dst.parent.mkdir(parents=True, exist_ok=True)
    out = VideoWriter(dst, fps, frames[0].shape[1], frames[0].shape[0], force=True)  # the project's writer
    for f in frames:
        out.write(f)
    out.close()


def wiper_angle(t: float) -> float:
    """The blades' angle (rad, from pointing left along the frame's bottom, turning clockwise up) at ``t`` (s): a sweep
    up to 100 deg and back, each half in a third of the period, resting flat for the last third."""
    phase = (t / WIPER_PERIOD_S) % 1.0
    up = min(phase * 3.0, 1.0) if phase < 1 / 3 else max(0.0, 2.0 - phase * 3.0)
    return np.radians(100.0) * (0.5 - 0.5 * np.cos(np.pi * up))  # slow at the ends, as a wiper's crank moves


def wiped(frame: np.ndarray, t: float) -> np.ndarray:
    """``frame`` with the ``wiper`` variant's two blades drawn over it at time ``t`` (s)."""
    import cv2

    h, w = frame.shape[:2]
    mask = np.zeros((h, w), np.float32)
    a = wiper_angle(t)
    for px, py in WIPER_PIVOTS:
        pivot = np.array([px * w, py * h])
        tip = pivot + WIPER_LENGTH * h * np.array([-np.cos(a), -np.sin(a)])
        cv2.line(mask, tuple(int(v) for v in pivot), tuple(int(v) for v in tip), 1.0, max(1, round(WIPER_WIDTH * w)))
    k = 2 * round(WIPER_WIDTH * w / 2) + 1
    mask = cv2.GaussianBlur(mask, (k, k), 0) * WIPER_OPACITY
    return (frame * (1.0 - mask[..., None]) + 15.0 * mask[..., None]).astype(np.uint8)


def portrait_picture(width: int, height: int) -> tuple[float, int]:
    """The ``portrait`` variant's picture of a ``width`` x ``height`` frame: (scale, top row in the portrait frame)."""
    scale = PORTRAIT_WIDTH / width
    return scale, (PORTRAIT_HEIGHT - round(height * scale)) // 2


def _portrait(frame: np.ndarray) -> np.ndarray:
    """``frame`` scaled into the middle of a black portrait frame (:func:`portrait_picture`)."""
    import cv2

    h, w = frame.shape[:2]
    scale, top = portrait_picture(w, h)
    out = np.zeros((PORTRAIT_HEIGHT, PORTRAIT_WIDTH, 3), np.uint8)
    picture = cv2.resize(frame, (PORTRAIT_WIDTH, round(h * scale)), interpolation=cv2.INTER_AREA)
    out[top : top + picture.shape[0]] = picture
    return out


def lens_maps(width: int, height: int, variant: str) -> tuple[np.ndarray, np.ndarray]:
    """``cv2.remap`` maps (float32, output pixel -> source pixel) of the ``fisheye`` or ``zoom`` variant."""
    v, u = np.mgrid[0:height, 0:width].astype(np.float64)
    src = lens_to_source(np.stack([u.ravel(), v.ravel()], axis=1), width, height, variant)
    return (src[:, 0].reshape(height, width).astype(np.float32), src[:, 1].reshape(height, width).astype(np.float32))


def lens_to_source(points: np.ndarray, width: int, height: int, variant: str) -> np.ndarray:
    """(n, 2) output pixels of the ``fisheye`` / ``zoom`` variant -> (n, 2) pixels of the source frame."""
    centre = np.array([(width - 1) / 2, (height - 1) / 2])
    d = points - centre
    if variant == "zoom":
        return centre + d / ZOOM
    half_diag = np.hypot(width / 2, height / 2)
    r = np.hypot(d[:, 0], d[:, 1]) / half_diag
    return centre + d * ((1 + FISHEYE_K * r**2) / (1 + FISHEYE_K))[:, None]


def source_to_lens(points: np.ndarray, width: int, height: int, variant: str) -> np.ndarray:
    """Inverse of :func:`lens_to_source`: (n, 2) source pixels -> output pixels (the fisheye's radius by Newton)."""
    centre = np.array([(width - 1) / 2, (height - 1) / 2])
    d = points - centre
    if variant == "zoom":
        return centre + d * ZOOM
    half_diag = np.hypot(width / 2, height / 2)
    target = np.hypot(d[:, 0], d[:, 1]) / half_diag  # source radius
    r = target.copy()
    for _ in range(30):  # r (1 + k r^2) / (1 + k) = target; monotonic for k > 0
        f = r * (1 + FISHEYE_K * r**2) / (1 + FISHEYE_K) - target
        r -= f / ((1 + 3 * FISHEYE_K * r**2) / (1 + FISHEYE_K))
    gain = np.where(target > 1e-12, r / np.maximum(target, 1e-12), 1 + FISHEYE_K)
    return centre + d * gain[:, None]


def lens_box(box: list[float], width: int, height: int, variant: str) -> list[int]:
    """A source-pixel box's bounding box in the ``fisheye`` / ``zoom`` output (its outline mapped, clipped)."""
    x1, y1, x2, y2 = box
    t = np.linspace(0.0, 1.0, 25)
    outline = np.concatenate(
        [
            np.stack([x1 + (x2 - x1) * t, np.full_like(t, y1)], 1),
            np.stack([x1 + (x2 - x1) * t, np.full_like(t, y2)], 1),
            np.stack([np.full_like(t, x1), y1 + (y2 - y1) * t], 1),
            np.stack([np.full_like(t, x2), y1 + (y2 - y1) * t], 1),
        ]
    )
    out = source_to_lens(outline, width, height, variant)
    lo = np.clip(out.min(axis=0), 0, [width - 1, height - 1])
    hi = np.clip(out.max(axis=0), 0, [width - 1, height - 1])
    return [round(lo[0]), round(lo[1]), round(hi[0]), round(hi[1])]


def rewrite_label(
    label: dict[str, Any], video: Path, variant: str, fps: float, step: int, scale: tuple[float, float], width: int,
    start: int = 0,
) -> dict[str, Any]:  # fmt: skip
    """The clip's label entry moved along with the rewrite (frames from ``start`` on, boxes). A contact frame dropped
    by the frame step moves to the next frame kept: the first frame of the new clip where the two touch."""
    out = json.loads(json.dumps(label))
    out["video"], out["fps"] = str(video), fps
    for key in ("contact_frame", "first_accident_frame"):
        if out.get(key) is not None:
            out[key] = -(-(int(out[key]) - start) // step)
    for p in out.get("participants", []):
        if "box" in p:
            x1, y1, x2, y2 = p["box"]
            if variant == "mirror":
                x1, x2 = width - x2, width - x1
            if variant in ("fisheye", "zoom"):
                p["box"] = lens_box([x1, y1, x2, y2], width, _height(video), variant)
                continue
            if variant == "portrait":
                k, top = portrait_picture(width, _height(DATA / label["video"]))  # the source clip's height
                p["box"] = [round(x1 * k), round(y1 * k) + top, round(x2 * k), round(y2 * k) + top]
                continue
            p["box"] = [round(x1 * scale[0]), round(y1 * scale[1]), round(x2 * scale[0]), round(y2 * scale[1])]
    return out


def _frame_count(video: Path) -> int:
    import av

    with av.open(str(video)) as inp:
        return sum(1 for _ in inp.decode(inp.streams.video[0]))


def _height(video: Path) -> int:
    import av

    with av.open(str(video)) as inp:
        return int(inp.streams.video[0].height)


def prepare(variant: str, names: list[str], work: Path, reuse: bool) -> Path:
    """The rewritten clips (kept with ``reuse`` where written before) and their label file (always written
    afresh) under ``work/variant``; returns the label file."""
    labels_path = work / variant / "labels.json"
    clips = {}
    for name in names:
        label_file, _ = all_labels()[name]
        raw = json.loads(label_file.read_text())["clips"][name]
        video = work / variant / "clips" / f"{name}.mp4"
        frames = _frame_count(DATA / raw["video"]) if variant in ("late", "end", "shot") else 0
        start = late_start(raw, frames) if variant in ("late", "shot") else 0
        stop = end_stop(raw, frames) if variant in ("end", "shot") else None
        if not (reuse and video.is_file()):
            rewrite_clip(DATA / raw["video"], video, variant, start, stop)
        clips[name] = rewrite_label(raw, video, variant, *variant_geometry(DATA / raw["video"], variant), start=start)
    labels_path.write_text(json.dumps({"format": "deepcrashtest-crash-labels", "version": 1, "clips": clips}))
    return labels_path


def summary(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """Reproduced / labelled, clips with an earlier contact, mean IoUs, and the misses of one variant."""
    labelled = [r for r in rows if r.get("reproduced") is not None]
    iou = {k: float(np.mean([r[k] for r in rows if r.get(k) is not None])) for k in ("iou_processed", "iou_simulated")}
    return {
        "reproduced": sum(bool(r["reproduced"]) for r in labelled),
        "labelled": len(labelled),
        "contact_before": sum(bool(r.get("contacts_before_crash")) for r in labelled),
        **{k: round(v, 4) for k, v in iou.items()},
        "missed": {r["clip"]: r.get("first_contact") for r in labelled if not r["reproduced"]},
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--variants", default=",".join(VARIANTS))
    ap.add_argument("--clips", default=None, help="Comma-separated clip names (default: every labelled crash clip).")
    ap.add_argument("--work", type=Path, default=Path("/tmp/deepcrashtest_fidelity_perturbed"))
    ap.add_argument("--reuse", action="store_true", help="Reuse rewritten clips and extractions in --work.")
    ap.add_argument("--stage2", action="store_true", help="Rerun stage 2 only (with --reuse).")
    ap.add_argument("--redetect", action="store_true", help="With --stage2: rerun the automatic crash detection first.")
    ap.add_argument("--json", action="store_true", help="Print one JSON object.")
    args = ap.parse_args()
    if not DATA.exists():
        print(json.dumps({"skipped": f"real data not found: {DATA}"}))
        return
    names = args.clips.split(",") if args.clips else [n for n in all_labels() if not n.startswith("highway")]
    fid_args = argparse.Namespace(max_frames=None, stage2=args.stage2, labelled_crash=False, redetect=args.redetect,
                                  reuse=args.reuse, video=False)  # fmt: skip
    result = {}
    for variant in args.variants.split(","):
        if variant not in VARIANTS + MORE_VARIANTS:
            sys.exit(f"unknown variant {variant!r} (one of {', '.join(VARIANTS + MORE_VARIANTS)})")
        labels_path = prepare(variant, names, args.work, args.reuse)
        labels = json.loads(labels_path.read_text())["clips"]
        from deepcrashtest.datasets.crash_labels import load_crash_labels

        parsed = load_crash_labels(labels_path)
        os.environ["CRASHDET_MOTION"] = str(args.work / variant / "motion")  # the clips' names repeat across variants
        rows = [run_clip(n, labels_path, parsed[n], args.work / variant / "out", fid_args) for n in labels]
        result[variant] = {"summary": summary(rows), "clips": rows}
        if not args.json:
            s = result[variant]["summary"]
            print(
                f"{variant}: reproduced {s['reproduced']}/{s['labelled']}, contact before the crash on "
                f"{s['contact_before']}, IoU {s['iou_processed']:.4f} / {s['iou_simulated']:.4f}, missed {s['missed']}",
                flush=True,
            )
    if args.json:
        print(json.dumps(result, indent=1))


if __name__ == "__main__":
    main()
