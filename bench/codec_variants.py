"""Labelled crash clips in the codecs, containers and pixel formats users' clips come in: extracted and scored.

Users' crash videos come from phones (HEVC 8- and 10-bit in QuickTime, full-range H.264, 3GP), downloads (VP9 in
WebM, AV1 in Matroska), dashcams (MJPEG or MPEG-4 Part 2 in AVI, MPEG-2 transport streams) and editors (H.264
4:4:4, 10-bit, odd frame sizes). Each clip is decoded once and written by PyAV in each kind below (same frames,
same frame rate; ``odd``: scaled to 853x479 first, the labels' boxes with it), then ``deepcrashtest extract`` runs
on the file through the CLI and ``evaluate fidelity``'s scoring compares it with the clip's labels (crash pair and
time, reprojection IoU), as ``bench/fidelity_crashes.py`` does for the clips as filmed.

Run: PYTHONPATH=src python bench/codec_variants.py [--clips a,b] [--kinds k1,k2] [--work DIR] [--json]
Per variant one line (exit code, traceback or not, reproduced, |dt|, IoU processed / replay), then the totals per
kind and per clip. Nothing is written into the repository; ``--work`` (default /tmp/deepcrashtest_codecs) holds
the files, the extractions and their label file.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from collections import defaultdict
from pathlib import Path
from typing import Any

import numpy as np
from fidelity_crashes import DATA, LABELS, ROOT  # the same clips, labels and checkout as the fidelity table

DEFAULT_CLIPS = "ccd_000031,ccd_000053,ccd_000882,dad_000478,dad_000487,dad_000512,dad_000550"
ODD_SIZE = (853, 479)

#: kind -> (file suffix, PyAV encoder, pixel format, encoder options, codec tag or None)
KINDS: dict[str, tuple[str, str, str, dict[str, str], str | None]] = {
    "hevc8": ("mp4", "libx265", "yuv420p", {"crf": "28", "preset": "ultrafast"}, "hvc1"),
    "hevc10": ("mov", "libx265", "yuv420p10le", {"crf": "28", "preset": "ultrafast"}, "hvc1"),
    "vp9": ("webm", "libvpx-vp9", "yuv420p", {"crf": "33", "b": "0", "deadline": "realtime", "cpu-used": "8"}, None),
    "av1": ("mkv", "libsvtav1", "yuv420p", {"crf": "35", "preset": "12"}, None),
    "mjpeg": ("avi", "mjpeg", "yuvj422p", {"q:v": "5"}, None),
    "mpeg4": ("avi", "mpeg4", "yuv420p", {"q:v": "5"}, None),
    "mpeg2ts": ("ts", "mpeg2video", "yuv420p", {"q:v": "5"}, None),
    "x264_444": ("mkv", "libx264", "yuv444p", {"crf": "23", "preset": "ultrafast"}, None),
    "x264_10bit": ("mp4", "libx264", "yuv420p10le", {"crf": "23", "preset": "ultrafast"}, None),
    "x264_full": ("mp4", "libx264", "yuvj420p", {"crf": "23", "preset": "ultrafast"}, None),
    "x264_odd": ("mkv", "libx264", "yuv444p", {"crf": "23", "preset": "ultrafast"}, None),
    "h264_3gp": ("3gp", "libx264", "yuv420p", {"crf": "30", "preset": "ultrafast", "profile": "baseline"}, None),
}


def all_labels() -> dict[str, dict[str, Any]]:
    """Every labelled clip's label as written in its file (name -> the JSON object), for writing variants' labels."""
    labels: dict[str, dict[str, Any]] = {}
    for f in LABELS:
        labels.update(json.loads(f.read_text())["clips"])
    return labels


def write(path: Path, frames: list[np.ndarray], rate: Any, kind: str) -> None:
    """``frames`` (BGR) into ``path`` as ``kind`` (:data:`KINDS`)."""
    import av
    import cv2

    _, codec, pix, opts, tag = KINDS[kind]
    if kind == "x264_odd":
        frames = [cv2.resize(f, ODD_SIZE, interpolation=cv2.INTER_AREA) for f in frames]
    with av.open(str(path), "w") as out:
        stream = out.add_stream(codec, rate=rate)
        stream.width, stream.height, stream.pix_fmt = frames[0].shape[1], frames[0].shape[0], pix
        stream.options = opts
        if tag:
            stream.codec_tag = tag
        for f in frames:
            for packet in stream.encode(av.VideoFrame.from_ndarray(np.ascontiguousarray(f), format="bgr24")):
                out.mux(packet)
        for packet in stream.encode():
            out.mux(packet)


def variant_label(label: dict[str, Any], video: Path, kind: str, size: tuple[int, int]) -> dict[str, Any]:
    """The clip's label for its ``kind`` file (boxes scaled for ``x264_odd``; ``size``: the clip's width, height)."""
    out = json.loads(json.dumps(label))
    out["video"] = str(video)
    if kind == "x264_odd":
        kx, ky = ODD_SIZE[0] / size[0], ODD_SIZE[1] / size[1]
        for p in out["participants"]:
            if "box" in p:
                p["box"] = [p["box"][0] * kx, p["box"][1] * ky, p["box"][2] * kx, p["box"][3] * ky]
    return out


def extract(video: Path, out: Path) -> dict[str, Any]:
    """``deepcrashtest extract`` through the CLI: exit code, seconds, whether stderr held a traceback."""
    t0 = time.time()
    cmd = [sys.executable, "-m", "deepcrashtest.cli", "extract", str(video), "-o", str(out), "--force"]
    env = dict(os.environ, PYTHONPATH=str(ROOT / "src"))
    p = subprocess.run(cmd, env=env, capture_output=True, text=True)
    return {"rc": p.returncode, "extract_s": round(time.time() - t0, 1), "traceback": "Traceback" in p.stderr}


def score(name: str, video: Path, out: Path, labels: Path) -> dict[str, Any]:
    """The fidelity of one extraction against its label (crash reproduced, |dt|, IoU processed / replay)."""
    from deepcrashtest.pipeline.fidelity import run_fidelity  # on the path through fidelity_crashes

    _, s = run_fidelity(
        out / "scenario.json", out / "fidelity", video=video, tracks=out / "tracks.csv", labels=str(labels),
        clip=name, make_video=False, force=True,
    )  # fmt: skip
    crash, rep = s["crash"], s["reprojection"]
    return {
        "reproduced": bool(crash.get("reproduced")),
        "dt_s": crash.get("dt_s"),
        "iou_processed": round(rep["processed"]["mean_iou"], 4),
        "iou_replay": round(rep["simulated"]["mean_iou"], 4),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--clips", default=DEFAULT_CLIPS)
    ap.add_argument("--kinds", default=",".join(KINDS))
    ap.add_argument("--work", type=Path, default=Path("/tmp/deepcrashtest_codecs"))
    ap.add_argument("--json", action="store_true", help="Print one JSON object at the end.")
    args = ap.parse_args()
    if not DATA.is_dir():
        print(json.dumps({"skipped": f"real data not found: {DATA}"}))
        return
    import av

    labels = all_labels()
    kinds = args.kinds.split(",")
    for k in kinds:
        if k not in KINDS:
            sys.exit(f"unknown kind {k!r} (one of {', '.join(KINDS)})")
    args.work.mkdir(parents=True, exist_ok=True)
    label_path = args.work / "labels.json"
    rows: list[dict[str, Any]] = []
    for clip in args.clips.split(","):
        with av.open(str(DATA / labels[clip]["video"])) as c:
            rate = c.streams.video[0].average_rate
            frames = [f.to_ndarray(format="bgr24") for f in c.decode(video=0)]
        size = (frames[0].shape[1], frames[0].shape[0])
        for kind in kinds:
            name = f"{clip}_{kind}"
            video = args.work / f"{name}.{KINDS[kind][0]}"
            write(video, frames, rate, kind)
            done = json.loads(label_path.read_text())["clips"] if label_path.exists() else {}
            done[name] = variant_label(labels[clip], video, kind, size)
            label_path.write_text(json.dumps({"format": "deepcrashtest-crash-labels", "version": 1, "clips": done}))
            out = args.work / "out" / name
            row = {"clip": clip, "kind": kind, **extract(video, out)}
            if (out / "scenario.json").is_file():
                row.update(score(name, video, out, label_path))
            rows.append(row)
            if not args.json:
                print(json.dumps(row), flush=True)
    totals: dict[str, dict[str, Any]] = {}
    for key in ("kind", "clip"):
        groups: dict[str, list[dict[str, Any]]] = defaultdict(list)
        for r in rows:
            groups[r[key]].append(r)
        totals[key] = {
            g: {
                "reproduced": sum(bool(r.get("reproduced")) for r in rs),
                "of": len(rs),
                "iou_processed": round(float(np.mean([r.get("iou_processed", 0.0) for r in rs])), 4),
            }
            for g, rs in groups.items()
        }
    summary = {
        "variants": len(rows),
        "exit_0": sum(r["rc"] == 0 for r in rows),
        "tracebacks": sum(bool(r["traceback"]) for r in rows),
        "reproduced": sum(bool(r.get("reproduced")) for r in rows),
        "iou_processed": round(float(np.mean([r.get("iou_processed", 0.0) for r in rows])), 4),
        "iou_replay": round(float(np.mean([r.get("iou_replay", 0.0) for r in rows])), 4),
        "by": totals,
    }
    print(json.dumps({"summary": summary, "rows": rows} if args.json else summary, indent=1))


if __name__ == "__main__":
    main()
