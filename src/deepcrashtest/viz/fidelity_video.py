"""``fidelity.mp4``: the original video with the simulated road users drawn over it.

Per frame: the simulated replay's road users as 3D boxes projected into the original camera
(the ego pose of the replay, the scenario's camera; :mod:`deepcrashtest.geometry.project`), the
tracked boxes as thin grey outlines with their id, the reprojection IoU of each simulated box
against its tracked box, and a header with the frame, video time and scenario time. From the
replay's first contact on, its two participants turn red and the contact point is marked; the
labelled contact (when a label is given) is announced in yellow with the labelled boxes. After the replay's last
step (the scenario ends at its crash) a line says so, and only the tracked boxes are drawn.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from deepcrashtest.datasets.crash_labels import CrashLabel
from deepcrashtest.eval.fidelity import FidelityResult, labelled_contact_time
from deepcrashtest.geometry.project import project_box_edges, project_camera_points, world_to_camera
from deepcrashtest.perception.annotate import id_colour
from deepcrashtest.scenario import Scenario
from deepcrashtest.video.source import open_video
from deepcrashtest.video.writer import VideoWriter

RED = (0, 0, 255)
YELLOW = (0, 230, 255)
GREY = (200, 200, 200)


def _text(img: np.ndarray, text: str, org: tuple[int, int], colour: tuple[int, int, int], scale: float = 0.6) -> None:
    import cv2

    cv2.putText(img, text, org, cv2.FONT_HERSHEY_SIMPLEX, scale, (0, 0, 0), 3, cv2.LINE_AA)
    cv2.putText(img, text, org, cv2.FONT_HERSHEY_SIMPLEX, scale, colour, 1, cv2.LINE_AA)


def _draw_segments(img: np.ndarray, seg: np.ndarray, colour: tuple[int, int, int], thickness: int) -> None:
    import cv2

    h, w = img.shape[:2]
    for (u0, v0), (u1, v1) in seg:
        if not np.isfinite([u0, v0, u1, v1]).all():
            continue
        ok, p, q = cv2.clipLine((0, 0, w, h), (int(round(u0)), int(round(v0))), (int(round(u1)), int(round(v1))))
        if ok:
            cv2.line(img, p, q, colour, thickness, cv2.LINE_AA)


def _by_frame(table: Any) -> dict[int, Any]:
    """Rows of a table (with a ``frame`` column) per frame index."""
    return {int(f): g for f, g in table.groupby("frame")} if len(table) else {}  # type: ignore[arg-type]


class FidelityPainter:
    """Draws one video frame of the fidelity overlay (see the module docstring)."""

    def __init__(
        self, scenario: Scenario, result: FidelityResult, sim: Any | None, label: CrashLabel | None = None
    ) -> None:
        self.sc = scenario
        self.sim = sim
        self.label = label
        self.pairs = result.pairs
        self.by_frame = _by_frame(result.pairs)
        self.first = result.crash.get("first_contact")
        self.vehicles = {v.id: v for v in scenario.vehicles()}

    def draw(self, frame_index: int, image: np.ndarray, tracks: Any) -> np.ndarray:
        """A copy of ``image`` (BGR) with the overlay of video frame ``frame_index``; ``tracks``: its tracks rows."""
        import cv2

        img = image.copy()
        t = self.sc.frame_time(frame_index)
        for r in tracks.itertuples(index=False):
            cv2.rectangle(img, (int(r.x1), int(r.y1)), (int(r.x2), int(r.y2)), GREY, 1, cv2.LINE_AA)
            _text(img, str(int(r.track_id)), (int(r.x1) + 2, int(r.y2) - 4), GREY, 0.45)
        contact_now = self.first is not None and self.first["scenario_time_s"] <= t + 1e-6
        if self.sim is not None:
            self._draw_sim(img, t, contact_now)
        header = (
            f"frame {frame_index}  video {self.sc.video_time(t):.2f}s  scenario {t:.2f}s   "
            "3D: simulated replay   grey: tracked"
        )
        _text(img, header, (10, 24), (255, 255, 255))
        if contact_now and self.first is not None:
            ids = "-".join(str(v) for v in self.first["participants"])
            speed = self.first["relative_speed_mps"] or 0.0
            msg = f"SIM CONTACT {ids} at {self.first['video_time_s']:.2f}s ({speed:.1f} m/s)"
            _text(img, msg, (10, 52), RED, 0.7)
        ended = self.replay_ended(t)
        if ended is not None:
            _text(img, ended, (10, 108), (255, 255, 255), 0.6)
        lab = self.label
        if lab is not None and lab.crash and lab.contact_frame is not None and frame_index >= lab.contact_frame:
            _text(
                img,
                f"LABELLED CONTACT frame {lab.contact_frame} ({labelled_contact_time(self.sc, lab):.2f}s)",
                (10, 80),
                YELLOW,
                0.7,
            )
            if abs(frame_index - lab.contact_frame) <= 2:
                for p in lab.participants:
                    if p.box is not None:
                        x1, y1, x2, y2 = (int(v) for v in p.box)
                        cv2.rectangle(img, (x1, y1), (x2, y2), YELLOW, 2, cv2.LINE_AA)
        return img

    def replay_ended(self, t: float) -> str | None:
        """The line saying the replay is over at scenario time ``t`` (s), or None while it runs: the scenario ends at
        its crash (or its last sample), so the video's frames after that have only their tracked boxes."""
        sim: Any = self.sim
        if sim is None or not len(sim.times) or t <= float(sim.times[-1]) + 0.5 * float(sim.dt):
            return None
        end = float(self.sc.video_time(float(sim.times[-1])))
        why = "the scenario ends at its crash" if self.sc.collision is not None else "the scenario ends there"
        return f"REPLAY ENDED at {end:.2f}s ({why}): tracked boxes only"

    def _draw_sim(self, img: np.ndarray, t: float, contact_now: bool) -> None:
        import cv2

        sim: Any = self.sim
        ego_pose = sim.pose_at(t, sim.vehicle_ids.index(self.sc.ego.id))
        if ego_pose is None:
            return
        hot = set(self.first["participants"]) if contact_now and self.first is not None else set()
        frame = self.sc.video_frame(t)
        rows = self.by_frame.get(frame if frame is not None else -1)
        ious = dict(zip(rows["agent_id"], rows["simulated_iou"], strict=True)) if rows is not None else {}
        camera = self.sc.camera.at_video_time(float(self.sc.video_time(t)))
        for i, vid in enumerate(sim.vehicle_ids):
            pose = sim.pose_at(t, i) if vid != self.sc.ego.id else None
            if pose is None:
                continue
            v = self.vehicles[vid]
            x, y, yaw = pose
            seg = project_box_edges(camera, ego_pose, x, y, yaw, v.length, v.width, v.height)  # type: ignore[arg-type]
            colour = RED if vid in hot else id_colour(vid)
            _draw_segments(img, seg, colour, 2)
            if vid in ious and np.isfinite(ious[vid]) and len(seg):
                top = seg.reshape(-1, 2)
                top = top[np.isfinite(top).all(axis=1)]
                if len(top):
                    u, v_ = top[:, 0].min(), top[:, 1].min()
                    _text(img, f"{vid} IoU {ious[vid]:.2f}", (int(max(u, 0)), int(max(v_ - 6, 14))), colour, 0.45)
        if hot and self.first is not None and self.first.get("point") is not None:
            px, py = self.first["point"]
            cam = world_to_camera(np.array([[px, py, 0.5]]), camera, *ego_pose)  # type: ignore[arg-type]
            uv = project_camera_points(cam, camera)[0]
            if np.isfinite(uv).all():
                cv2.drawMarker(img, (int(uv[0]), int(uv[1])), RED, cv2.MARKER_TILTED_CROSS, 28, 3, cv2.LINE_AA)


def _read_fps(video: str | Path, scenario: Scenario) -> float | None:
    """The frame rate ``video`` is read at: the scenario's for an image folder (no frame rate of its own; frame numbers
    are the file numbers) and for a video ``extract`` re-timed by its clock (``provenance.parameters.time_base``: the
    overlay plays in real time, as the annotated video does), else the file's own (None)."""
    retimed = isinstance(scenario.provenance.parameters.get("time_base"), dict)
    return scenario.source.fps if Path(video).is_dir() or retimed else None


def write_fidelity_video(
    scenario: Scenario,
    result: FidelityResult,
    sim: Any | None,
    video: str | Path,
    tracks: Any,
    output: str | Path,
    label: CrashLabel | None = None,
    force: bool = False,
    max_frames: int | None = None,
) -> dict[str, Any]:
    """Write the overlay video (H.264 mp4, atomically) of ``video``; returns its path and frame count."""
    painter = FidelityPainter(scenario, result, sim, label)
    by_frame = _by_frame(tracks)
    empty = tracks.iloc[:0]
    with open_video(video, _read_fps(video, scenario), scenario.source.width) as src:
        meta = src.meta
        with VideoWriter(output, meta.fps, meta.width, meta.height, force=force) as writer:
            for frame in src:
                if max_frames is not None and frame.index >= max_frames:
                    break
                writer.write(painter.draw(frame.index, frame.image, by_frame.get(frame.index, empty)))
            n = writer.frames_written
    return {"path": str(output), "frames": n}


def render_frames(
    painter: FidelityPainter, video: str | Path, tracks: Any, frames: list[int], folder: str | Path
) -> list[Path]:
    """PNG files of chosen frames of the overlay (for looking at them), ``folder/fidelity_NNNN.png``."""
    import cv2

    out = Path(folder)
    out.mkdir(parents=True, exist_ok=True)
    want = set(frames)
    by_frame = _by_frame(tracks)
    paths = []
    with open_video(video, _read_fps(video, painter.sc), painter.sc.source.width) as src:
        for frame in src:
            if frame.index in want:
                p = out / f"fidelity_{frame.index:04d}.png"
                cv2.imwrite(str(p), painter.draw(frame.index, frame.image, by_frame.get(frame.index, tracks.iloc[:0])))
                paths.append(p)
            if frame.index >= max(want):
                break
    return paths
