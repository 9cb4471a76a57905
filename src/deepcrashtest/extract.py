"""``deepcrashtest extract``: one decoding pass over a video -> tracks.csv, annotated.mp4 (, scenario.json).

Stage 1a (this module today): detect + track vehicles, draw them. Later stages hook into the same
pass through ``on_frame`` callbacks and add their outputs after tracking (see the marked place).
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

from deepcrashtest.errors import UserError
from deepcrashtest.fileio import atomic_path, check_writable, ensure_output_dir
from deepcrashtest.perception.annotate import Annotator
from deepcrashtest.perception.detect import make_detector
from deepcrashtest.perception.track import FrameTracks, track_video
from deepcrashtest.ui import track as progress
from deepcrashtest.video.source import open_video
from deepcrashtest.video.writer import VideoWriter

DEFAULT_DETECTOR = "ssd-mobilenet"
DEFAULT_DETECT_EVERY = 5


def run_extract(
    video: str | Path,
    output: str | Path,
    detector: str = DEFAULT_DETECTOR,
    detect_every: int = DEFAULT_DETECT_EVERY,
    max_frames: int | None = None,
    fps: float | None = None,
    force: bool = False,
    annotate: bool = True,
) -> dict[str, Any]:
    """Detect and track every vehicle in ``video``; write ``output``/tracks.csv and annotated.mp4.

    Returns a summary: frames, tracks, mean track length (frames), processing fps, warnings.
    """
    if detect_every < 1:
        raise UserError(f"--detect-every must be >= 1 (got {detect_every})")
    if max_frames is not None and max_frames < 1:
        raise UserError(f"--max-frames must be >= 1 (got {max_frames})")
    src_path = Path(video)
    if not src_path.exists():
        raise UserError(f"{src_path}: no such video file or image folder")
    out = Path(output)
    if out.exists() and not out.is_dir():
        raise UserError(f"{out}: exists and is not a directory")
    csv_path, mp4_path = out / "tracks.csv", out / "annotated.mp4"
    for p in (csv_path, mp4_path) if annotate else (csv_path,):
        if p.exists() and not force:
            raise UserError(f"{p}: already exists (use --force to overwrite)")
    det = make_detector(detector)
    t0 = time.perf_counter()
    with open_video(src_path, fps) as source:
        meta = source.meta
        ensure_output_dir(out)
        total = min(meta.frame_count, max_frames) if max_frames else meta.frame_count
        frames = progress(source, "extract", total=total or None)
        if annotate:
            drawer = Annotator(meta.fps)
            with VideoWriter(mp4_path, meta.fps, meta.width, meta.height, force=force) as writer:

                def on_frame(ft: FrameTracks) -> None:
                    writer.write(drawer.draw(ft))

                df = track_video(frames, det, detect_every, max_frames, on_frame=on_frame, fps=meta.fps)
        else:
            df = track_video(frames, det, detect_every, max_frames, fps=meta.fps)
    elapsed = time.perf_counter() - t0
    if meta.decoded_frames == 0:
        raise UserError(f"{src_path}: no frame could be decoded")
    check_writable(csv_path, force)
    with atomic_path(csv_path, force=force) as tmp:
        df.to_csv(tmp, index=False, float_format="%.3f")

    # ----------------------------------------------------------------------------------------
    # GEOMETRY STAGE GOES HERE: the geometry helper turns `df` (+ meta, ego-motion gathered in an
    # on_frame hook in the same pass) into a Scenario and writes out / "scenario.json".
    # ----------------------------------------------------------------------------------------

    n_frames = min(meta.decoded_frames, max_frames) if max_frames else meta.decoded_frames
    lengths = df.groupby("track_id").size() if len(df) else None
    return {
        "video": str(src_path),
        "output": str(out),
        "tracks_csv": str(csv_path),
        "annotated_mp4": str(mp4_path) if annotate else None,
        "detector": getattr(det, "name", detector),
        "detect_every": detect_every,
        "fps_video": round(meta.fps, 3),
        "width": meta.width,
        "height": meta.height,
        "frames": int(n_frames),
        "tracks": int(df["track_id"].nunique()) if len(df) else 0,
        "mean_track_length_frames": round(float(lengths.mean()), 2) if lengths is not None else 0.0,
        "fps_achieved": round(n_frames / elapsed, 2) if elapsed > 0 else None,
        "seconds": round(elapsed, 2),
        "warnings": list(meta.warnings),
    }
