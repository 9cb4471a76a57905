"""``report.html``: one self-contained HTML file describing a run (images inline as base64 PNG).

Composable: each ``*_section`` builder returns a :class:`Section` (or None when it has nothing to
show), and :func:`write_report` puts any sequence of them into one file. Extraction, simulation and
the search each add the sections they know about; :func:`scenario_sections` builds the ones a
Scenario file (plus optional video, simulation metrics and search table) can give.

Plots use matplotlib's Agg canvas directly (no pyplot state), world frame x forward / y left,
metres and seconds.
"""

from __future__ import annotations

import base64
import html
import io
import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import numpy as np

from deepcrashtest import __version__
from deepcrashtest.errors import UserError
from deepcrashtest.fileio import atomic_write_text
from deepcrashtest.scenario import Collision, Scenario, Vehicle
from deepcrashtest.viz.plots import birdseye_figure, observed_mask, plot_observed, time_axes
from deepcrashtest.viz.sheet_thumbs import SHEET_FRAMES, SHEET_THUMB_WIDTH, SheetThumbs, sheet_frames, thumb_size
from deepcrashtest.viz.style import CLASS_DESCRIPTIONS, EGO_COLOUR, OBSERVED_NOTE, vehicle_colour

#: The distance plot's axis stops here (metres): farther road users do not matter for a crash.
DISTANCE_PLOT_MAX_M = 100.0
#: Where a collision entry came from, in words.
COLLISION_SOURCES = {
    "video-auto": "detected in the video",
    "user": "given by the user",
    "labels": "from the dataset's labels",
    "simulated": "found by the simulator",
}


@dataclass
class Section:
    """One part of the report: a title and its body (HTML built by the builders, text escaped)."""

    title: str
    body: str

    @property
    def anchor(self) -> str:
        return "".join(c if c.isalnum() else "-" for c in self.title.lower()).strip("-")


# --------------------------------------------------------------------------- HTML pieces
def esc(value: Any) -> str:
    return html.escape(str(value), quote=True)


def fmt(value: Any, digits: int = 3) -> str:
    """A number rounded for people; None/NaN as a dash."""
    if value is None:
        return "-"
    if isinstance(value, bool | np.bool_):
        return "yes" if value else "no"
    if isinstance(value, int | np.integer):
        return str(int(value))
    if isinstance(value, float | np.floating):
        return "-" if not math.isfinite(float(value)) else f"{float(value):.{digits}g}"
    return str(value)


def table(rows: Iterable[tuple[str, Any]]) -> str:
    """A two-column key/value table (values formatted with :func:`fmt`, escaped)."""
    cells = "".join(f"<tr><th>{esc(k)}</th><td>{esc(fmt(v))}</td></tr>" for k, v in rows)
    return f'<table class="kv">{cells}</table>'


def figure_png(fig: Any, tight: bool | None = None) -> str:
    """Base64 PNG of a matplotlib Figure (rendered with the Agg canvas).

    A figure with a layout engine (the report's are constrained, :func:`_figure`, ``birdseye_figure``) already
    fits its labels and legends inside the canvas: it is drawn once (its layout runs in that draw) and the
    canvas's pixels are written, the blank rows and columns beyond 0.1 in around what is drawn cut off (an
    equal-aspect plot leaves them; :func:`_inked`). ``savefig(..., bbox_inches="tight")`` drew it twice (a first
    draw without rendering for the layout, then again) and measured it once more, for the same picture: the
    three plots of a report cost ~0.5 s of CPU more that way. ``tight``: crop (or grow) the canvas to the
    artists, for artists the layout does not place (default: only without a layout engine).
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from PIL import Image  # matplotlib's own PNG writer

    canvas = FigureCanvasAgg(fig)
    buf = io.BytesIO()
    crop_to_artists = fig.get_layout_engine() is None if tight is None else tight
    if crop_to_artists:
        fig.savefig(buf, format="png", dpi=fig.dpi, bbox_inches="tight")
    else:
        canvas.draw()
        rgba = np.asarray(canvas.buffer_rgba())
        Image.fromarray(_inked(rgba, fig.get_facecolor(), round(0.1 * fig.dpi))).save(buf, format="png")
    return base64.b64encode(buf.getvalue()).decode("ascii")


def _inked(rgba: np.ndarray, background: Sequence[float], pad: int) -> np.ndarray:
    """``rgba`` (H, W, 4 uint8) cut to the pixels unlike ``background`` (RGBA, 0-1) and ``pad`` px around them."""
    ink = np.any(rgba != np.round(np.asarray(background) * 255).astype(np.uint8), axis=2)
    rows, cols = np.flatnonzero(ink.any(axis=1)), np.flatnonzero(ink.any(axis=0))
    if not len(rows):
        return rgba
    h, w = ink.shape
    return rgba[max(rows[0] - pad, 0) : min(rows[-1] + 1 + pad, h), max(cols[0] - pad, 0) : min(cols[-1] + 1 + pad, w)]


def img(png_b64: str, alt: str, mime: str = "image/png") -> str:
    return f'<img alt="{esc(alt)}" src="data:{mime};base64,{png_b64}">'


def _figure(width: float, height: float) -> Any:
    from matplotlib.figure import Figure

    return Figure(figsize=(width, height), dpi=100, layout="constrained")


def who(sc: Scenario, vid: int) -> str:
    """``the ego`` or ``agent 16 (car, D1T2)``."""
    if vid == sc.ego.id:
        return "the ego"
    try:
        v = sc.vehicle(vid)
    except KeyError:
        return f"road user {vid}"
    return f"agent {vid} ({v.category}{', ' + v.trajectory_class if v.trajectory_class else ''})"


def time_text(sc: Scenario, t: float) -> str:
    """A scenario time with its video time and frame (the one mapping, :meth:`Scenario.video_frame`)."""
    vt = float(sc.video_time(t))
    f = sc.video_frame(t)
    if f is not None:
        return f"scenario t = {t:.2f} s = video t = {vt:.2f} s (frame {f})"
    end = sc.source.frame_count / sc.source.fps
    where = "before the video starts" if vt < 0 else f"after the video's end at {end:.2f} s"
    return f"scenario t = {t:.2f} s = video t = {vt:.2f} s, {where}"


def collision_text(sc: Scenario, c: Collision) -> str:
    """One sentence: who collided with whom, when (scenario and video time), how fast, from where."""
    speed = f", relative speed {c.relative_speed:.2f} m/s" if c.relative_speed is not None else ""
    kind = "" if c.involves_ego else "third-party crash: "
    return (
        f"{kind}{who(sc, c.other_id)} and {who(sc, c.agent_id)} at {time_text(sc, c.time_s)}{speed} "
        f"({COLLISION_SOURCES.get(c.source, c.source)})"
    )


def flat_items(data: Mapping[str, Any], prefix: str = "") -> list[tuple[str, Any]]:
    """Nested mappings as ``(dotted.key, value)`` rows; lists of numbers joined."""
    rows: list[tuple[str, Any]] = []
    for k, v in data.items():
        key = f"{prefix}{k}"
        if isinstance(v, Mapping):
            rows += flat_items(v, key + ".")
        elif isinstance(v, list | tuple):
            rows.append((key, ", ".join(fmt(x, 4) for x in v)))
        else:
            rows.append((key, v))
    return rows


# --------------------------------------------------------------------------- sections
def overview_section(sc: Scenario) -> Section:
    """Name, stage, road users, duration, classes, time mapping, collision and provenance."""
    classes = sc.class_counts()
    n = sc.source.frame_count
    rows: list[tuple[str, Any]] = [
        ("name", sc.name),
        ("schema version", sc.schema_version),
        ("stage", sc.stage),
        ("duration (s)", sc.duration()),
        ("road users", category_listing(sc)),
        ("trajectory classes", ", ".join(f"{k}: {n}" for k, n in classes.items()) or "-"),
        (
            "time mapping",
            f"scenario t = video t + {sc.source.time_offset_s:.2f} s; the video covers scenario t "
            f"{sc.frame_time(0):.2f}-{sc.frame_time(n):.2f} s ({n} frames at {_rate(sc.source)})",
        ),
        (
            "road",
            f"{sc.road.lane_count} lanes x {sc.road.lane_width:.2f} m, ego lane {sc.road.ego_lane}"
            + (
                f", {sc.road.oncoming_lane_count} oncoming lane(s)"
                + (f" beyond a {sc.road.median_width:.1f} m median" if sc.road.median_width else "")
                if sc.road.oncoming_lane_count
                else ""
            )
            + (", left-hand traffic" if sc.road.driving_side == "left" else "")
            + f", from {sc.road.source}"
            + (" (no lanes seen: inferred from the road users' paths)" if sc.road.source == "road_users" else ""),
        ),
        ("collision in the scenario", collision_text(sc, sc.collision) if sc.collision is not None else "none"),
        ("made by", f"deepcrashtest {sc.provenance.package_version}: {sc.provenance.command or '-'}"),
        ("seed", sc.provenance.seed),
    ]
    body = table(rows)
    params = flat_items(sc.provenance.parameters)
    if params:
        body += f"<details><summary>Parameters ({len(params)})</summary>{table(params)}</details>"
    if sc.provenance.history:
        body += "<h3>Edit history</h3><ol>" + "".join(f"<li>{esc(h)}</li>" for h in sc.provenance.history) + "</ol>"
    used = [k for k in CLASS_DESCRIPTIONS if k in classes]
    if used:
        body += "<p>Classes: " + "; ".join(f"<b>{k}</b> {esc(CLASS_DESCRIPTIONS[k])}" for k in used) + ".</p>"
    return Section("Scenario", body)


def category_listing(sc: Scenario) -> str:
    """Agents per road-user category, e.g. ``car: 3, motorcycle (with rider): 1, pedestrian: 2``."""
    counts: dict[str, int] = {}
    for a in sc.agents:
        counts[a.category] = counts.get(a.category, 0) + 1
    order = ("car", "van", "truck", "bus", "motorcycle", "bicycle", "pedestrian")
    label = {"motorcycle": "motorcycle (with rider)", "bicycle": "bicycle (with rider)"}
    return ", ".join(f"{label.get(k, k)}: {counts[k]}" for k in order if k in counts) or "-"


def _frame_rate(sc: Scenario) -> Any:
    """The source's frame rate as the report says it: where it varies, and where the dashcam's clock re-timed it."""
    s = sc.source
    if s.frame_times is not None:
        return f"variable (frames' own times), mean {s.fps:.3f}"
    base = sc.provenance.parameters.get("time_base")
    if isinstance(base, dict) and base.get("source") == "overlay clock":
        return f"{s.fps:g}, the dashcam's clock's real time (the file says {base.get('file_fps')})"
    return s.fps


def source_section(sc: Scenario) -> Section:
    """Facts about the source video (or label file) the scenario came from."""
    s = sc.source
    rows: list[tuple[str, Any]] = [
        ("kind", s.kind),
        ("file", Path(s.path).name),
        ("frame rate (fps)", _frame_rate(sc)),
        ("frames", s.frame_count),
        ("length (s)", sc.video_time(sc.frame_time(s.frame_count))),
        ("scenario time of frame 0 (s)", sc.frame_time(0)),
        ("size (px)", f"{s.width} x {s.height}"),
        ("SHA-256", s.sha256 or "-"),
    ]
    if s.frame_rate_note:
        rows.append(("frame-rate note", s.frame_rate_note))
    return Section("Source video", table(rows))


def camera_section(sc: Scenario) -> Section:
    """The camera model and where each of its calibration values came from."""
    c = sc.camera
    rows: list[tuple[str, Any]] = [
        ("focal length fx, fy (px)", f"{c.fx:.1f}, {c.fy:.1f}"),
        ("principal point cx, cy (px)", f"{c.cx:.1f}, {c.cy:.1f}"),
        ("horizontal field of view (deg)", math.degrees(2 * math.atan(sc.source.width / (2 * c.fx)))),
        ("distortion", ", ".join(f"{d:.4g}" for d in c.distortion) or "none"),
        ("intrinsics from", c.intrinsics_source),
        ("height above road (m)", c.height_m),
        ("height from", c.height_source),
        ("pitch, down + (deg)", math.degrees(c.pitch_rad)),
        ("pitch from", c.pitch_source),
        ("roll (deg)", math.degrees(c.roll_rad)),
        ("ahead of ego centre (m)", c.forward_offset_m),
    ]
    known = known_speed(sc)
    if known is not None:
        source = "the picture's GPS overlay" if known.get("source") == "overlay" else "given (--ego-speed)"
        rows.append(("ego speed known apart from the images", f"{source}: {known.get('what', '')}"))
    return Section("Camera and calibration", table(rows))


def known_speed(sc: Scenario) -> Mapping[str, Any] | None:
    """The ego's speed the self-calibration was offered apart from the images (the user's, the picture's overlay):
    ``source``, ``what``, ``times_s`` (video time, s) and ``kmh``; None where there was none."""
    calib = sc.provenance.parameters.get("self_calibration")
    known = calib.get("known_speed") if isinstance(calib, Mapping) else None
    return known if isinstance(known, Mapping) and known.get("kmh") else None


def collision_frame(sc: Scenario | None) -> int | None:
    """The video frame of the scenario's collision (None without one, or outside the video)."""
    return None if sc is None or sc.collision is None else sc.video_frame(sc.collision.time_s)


def contact_sheet_section(
    video: str | Path,
    frames: int = SHEET_FRAMES,
    columns: int = 4,
    thumb_width: int = SHEET_THUMB_WIDTH,
    sc: Scenario | None = None,
    kept: SheetThumbs | None = None,
) -> Section:
    """A grid of ``frames`` evenly spaced frames of ``video`` (the annotated extraction output).

    Each is titled ``#k``, its frame number, video time and (with ``sc``) scenario time; the plots
    mark the same ``#k`` at the same scenario time (:func:`sheet_marks`). ``kept``: the thumbnails the pass
    kept of the frames it wrote to ``video`` (:class:`SheetThumbs`); only frames it did not keep are decoded.
    """
    import cv2

    if frames < 1 or columns < 1:
        raise UserError(f"contact sheet needs frames >= 1 and columns >= 1 (got {frames}, {columns})")
    if kept is not None and kept.thumb_width == thumb_width:
        indices = sheet_frames(kept.count, frames, collision_frame(sc))
        found = [kept.frame(i) for i in indices]
        info = kept.info()
        missing = [i for i, im in zip(indices, found, strict=True) if im is None]
        decoded = dict(zip(missing, _decoded_thumbs(video, missing, thumb_width), strict=True))
        thumbs = [im if im is not None else decoded[i] for i, im in zip(indices, found, strict=True)]
    else:
        indices, thumbs, info = _video_sheet(video, frames, thumb_width, sc)
    if not thumbs:
        return Section("Annotated frames", f"<p>{esc(Path(video).name)}: no frames.</p>")
    rows = math.ceil(len(thumbs) / columns)
    th, tw = thumbs[0].shape[:2]
    band = 36 if sc is not None else 22  # caption rows above each thumbnail
    # composed with NumPy + OpenCV and JPEG-encoded: a matplotlib grid of 12 images took ~60 % of the report
    sheet = np.full((rows * (th + band), columns * tw, 3), 255, np.uint8)
    for k, (i, im) in enumerate(zip(indices, thumbs, strict=False)):
        y, x = (k // columns) * (th + band), (k % columns) * tw
        sheet[y + band : y + band + im.shape[0], x : x + im.shape[1]] = im[:th, :tw]
        hit = i == collision_frame(sc)
        lines = [f"#{k + 1}  frame {i}, video {i / info['fps']:.2f} s" + ("  COLLISION" if hit else "")]
        if sc is not None:
            lines.append(f"scenario t = {sc.frame_time(i):.2f} s")
        for n, text in enumerate(lines):
            colour = (200, 0, 0) if hit else (0, 0, 0)  # RGB
            cv2.putText(sheet, text, (x + 6, y + 15 + 15 * n), cv2.FONT_HERSHEY_SIMPLEX, 0.42, colour, 1, cv2.LINE_AA)
    ok, jpeg = cv2.imencode(".jpg", cv2.cvtColor(sheet, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, 85])
    if not ok:
        raise UserError("could not encode the contact sheet")
    caption = (
        f"<p>{esc(Path(video).name)}: {info['width']} x {info['height']} px, {info['fps']:.3g} fps, "
        f"{info['duration_s']:.2f} s, {len(thumbs)} frames evenly spaced. "
        + ("The plots below mark the same #k at the same scenario time." if sc is not None else "")
        + "</p>"
    )
    sheet_b64 = base64.b64encode(jpeg.tobytes()).decode("ascii")
    return Section("Annotated frames", caption + img(sheet_b64, "contact sheet of annotated frames", "image/jpeg"))


def _video_sheet(
    video: str | Path, frames: int, thumb_width: int, sc: Scenario | None
) -> tuple[list[int], list[np.ndarray], dict[str, Any]]:
    """The sheet's frame indices, their thumbnails and the video's facts, decoded from ``video``."""
    from deepcrashtest.viz.video_frames import VideoFrames

    vf = VideoFrames(video)
    try:
        indices = sheet_frames(vf.frame_count, frames, collision_frame(sc))
        return indices, _thumbs_of(vf, indices, thumb_width), vf.info()
    finally:
        vf.close()


def _decoded_thumbs(video: str | Path, indices: list[int], thumb_width: int) -> list[np.ndarray]:
    """Thumbnails of frames ``indices`` decoded from ``video`` (not opened when there are none)."""
    if not indices:
        return []
    from deepcrashtest.viz.video_frames import VideoFrames

    vf = VideoFrames(video)
    try:
        return _thumbs_of(vf, indices, thumb_width)
    finally:
        vf.close()


def _thumbs_of(vf: Any, indices: list[int], thumb_width: int) -> list[np.ndarray]:
    import cv2

    thumbs = []
    for i in indices:
        rgb = vf.frame(i)
        h, w = rgb.shape[:2]
        thumbs.append(cv2.resize(rgb, thumb_size(w, h, thumb_width), interpolation=cv2.INTER_AREA))
    return thumbs


def sheet_marks(sc: Scenario, frame_count: int, frames: int = SHEET_FRAMES) -> list[tuple[str, float]]:
    """``(#k, scenario time)`` of the contact sheet's frames, for the time plots."""
    indices = sheet_frames(frame_count, frames, collision_frame(sc))
    return [(f"#{k + 1}", sc.frame_time(i)) for k, i in enumerate(indices)]


def birdseye_section(sc: Scenario, sim_states: Mapping[int, np.ndarray] | None = None) -> Section:
    """Bird's-eye plot of every trajectory on the road (:func:`deepcrashtest.viz.plots.birdseye_figure`).

    ``sim_states``: optional simulated paths per vehicle id ((T, 2+) arrays, x, y first), drawn dashed.
    """
    fig = birdseye_figure(sc, title=sc.name, sim_paths=sim_states)
    body = (
        "<p>Dots mark where each road user is first seen; numbers are agent ids. "
        f"{esc(OBSERVED_NOTE.replace('dashed/faded', 'dotted'))}.</p>"
    )
    # a zoomed panel's frame on the overview may reach beyond its axes, where the layout leaves no room
    png = figure_png(fig, tight=len(fig.axes) > 1)
    return Section("Bird's-eye view", body + img(png, "bird's-eye plot of the trajectories"))


def distance_to_ego(sc: Scenario, v: Vehicle) -> tuple[np.ndarray, np.ndarray]:
    """Times (s) and centre-to-centre distance (m) from the ego, where both exist."""
    a, e = v.trajectory.arrays(), sc.ego.trajectory.arrays()
    keep = (a["t"] >= e["t"][0]) & (a["t"] <= e["t"][-1])
    t = a["t"][keep]
    d = np.hypot(a["x"][keep] - np.interp(t, e["t"], e["x"]), a["y"][keep] - np.interp(t, e["t"], e["y"]))
    return t, d


def motion_section(sc: Scenario, marks: Sequence[tuple[str, float]] = ()) -> Section:
    """Speed of every road user, and each agent's distance from the ego, over scenario time.

    Solid where observed, dotted where extrapolated/led in; the video's span shaded, its time on the
    top axis; ``marks`` (the contact sheet's ``#k``) at their scenario times.
    """
    n = len(sc.vehicles())
    fig = _figure(11, 6.2)
    ax_v, ax_d = fig.subplots(2, 1, sharex=True)
    dmax = 0.0
    for v in sc.vehicles():
        tr = v.trajectory.arrays()
        col = vehicle_colour(v, sc.ego.id)
        is_ego = v.id == sc.ego.id
        obs = observed_mask(v)
        label = "ego" if is_ego else f"{v.id} {v.category} {v.trajectory_class or ''}".strip()
        plot_observed(ax_v, tr["t"], tr["speed"] * 3.6, obs, col, 2.0 if is_ego else 0.9, label=label)
        if not is_ego:
            t, d = distance_to_ego(sc, v)
            if len(t):
                keep = np.isin(tr["t"], t)
                plot_observed(ax_d, t, d, obs[keep] if keep.sum() == len(t) else np.ones(len(t), bool), col, 0.9)
                i = int(np.argmin(d))
                if d[i] <= DISTANCE_PLOT_MAX_M:
                    ax_d.annotate(str(v.id), (t[i], d[i]), fontsize=6, color="#333")
                dmax = max(dmax, float(d.max()))
    known = known_speed(sc)
    if known is not None and known.get("source") == "overlay":  # what the picture says, beside what was measured
        t_known = sc.scenario_time(np.asarray(known["times_s"], dtype=float))
        ax_v.plot(t_known, known["kmh"], "kx", ms=5, label="ego: the picture's GPS overlay")
    ax_v.set_ylabel("speed (km/h)")
    ax_v.legend(
        fontsize=6 if n > 12 else 7, loc="upper left", bbox_to_anchor=(1.01, 1.0), ncols=1 + n // 16, title="road user"
    )
    ax_d.set_ylabel("distance to ego, centre to centre (m)")
    ax_d.set_xlabel("scenario time (s)")
    ax_d.set_ylim(0, min(max(dmax, 1.0) * 1.05, DISTANCE_PLOT_MAX_M))
    ax_v.set_ylim(bottom=0)
    time_axes(ax_v, sc, marks)
    time_axes(ax_d, sc, (), top_axis=False)
    for ax in (ax_v, ax_d):
        ax.grid(alpha=0.3)
    closest = []
    for v in sc.agents:
        t, d = distance_to_ego(sc, v)
        if len(t):
            i = int(np.argmin(d))
            closest.append((float(d[i]), v.id, float(t[i])))
    closest.sort()
    rows = [(f"agent {vid}", f"{d:.2f} m at {time_text(sc, t)}") for d, vid, t in closest[:5]]
    note = (
        "<p>Solid: observed in the video; dotted: extrapolated, lead-in or step-back. Shaded: the video's span "
        "(video time on the top axis). Red dashed line: the collision. "
        + (f"Distances beyond {DISTANCE_PLOT_MAX_M:g} m are off the plot." if dmax > DISTANCE_PLOT_MAX_M else "")
        + "</p>"
    )
    body = note + img(figure_png(fig), "speed and distance over time")
    if rows:
        body += "<h3>Closest approaches (centre to centre)</h3>" + table(rows)
    return Section("Speed and distance over time", body)


def lane_offset_section(sc: Scenario) -> Section | None:
    """The ego's lateral offset in its lane and its lane index over time (None without a lane timeline)."""
    lt = sc.road.lane_timeline
    if lt is None or not lt.t:
        return None
    fig = _figure(10, 3.2)
    ax = fig.add_subplot()
    ax.plot(lt.t, lt.lateral_offset, color=EGO_COLOUR, lw=1.5, label="offset from lane centre")
    for edge in (-sc.road.lane_width / 2, sc.road.lane_width / 2):
        ax.axhline(edge, color="#555", ls="--", lw=0.8)
    ax.set_xlabel("scenario time (s)")
    ax.set_ylabel("left of lane centre (m)")
    time_axes(ax, sc)
    ax2 = ax.twinx()
    ax2.step(lt.t, lt.lane_index, where="post", color="#1e88e5", lw=1.0, label="lane index")
    ax2.set_ylabel("lane (0 = rightmost)")
    ax2.set_yticks(range(sc.road.lane_count))
    ax.grid(alpha=0.3)
    changes = int(np.count_nonzero(np.diff(np.asarray(lt.lane_index))))
    body = f"<p>{changes} lane change(s). Dashed lines: the lane's edges.</p>"
    return Section("Lane offset", body + img(figure_png(fig), "lane offset over time"))


SIM_UNITS = {
    "collision_time": "s",
    "delta_v_ego": "m/s",
    "delta_v_other": "m/s",
    "relative_speed": "m/s",
    "min_distance": "m",
    "min_ttc": "s",
    "aeb_time": "s",
    "warning_time": "s",
    "robustness": "m",
}


def simulation_section(
    metrics: Mapping[str, Any] | Any, title: str = "Simulation outcome", sc: Scenario | None = None
) -> Section:
    """The simulation's outcome: a verdict that names the ego's collision and counts the others, the
    metrics with units, and every collision (a dict of metrics, optionally with ``collisions``, or a
    SimResult)."""
    m = getattr(metrics, "metrics", metrics)
    if not isinstance(m, Mapping):
        raise UserError(f"simulation metrics must be a JSON object, got {type(m).__name__}")
    collisions = list(
        getattr(metrics, "collisions", None)
        or (metrics.get("collisions") if isinstance(metrics, Mapping) else None)
        or []
    )
    m = dict(m)
    ego = sc.ego.id if sc is not None else 0
    ego_hit = next((c for c in collisions if ego in c.get("vehicles", [])), None)
    if m.get("delta_v_ego") is None and ego_hit is not None:  # the metrics leave it out unless first overall
        m["delta_v_ego"] = (ego_hit.get("delta_v") or {}).get(str(ego))
    n_all = m.get("n_collisions", len(collisions))
    n_all = len(collisions) if n_all is None else int(n_all)
    name = (lambda i: who(sc, int(i))) if sc is not None else (lambda i: "the ego" if int(i) == ego else f"agent {i}")
    at = (lambda t: time_text(sc, float(t))) if sc is not None else (lambda t: f"t = {float(t):.2f} s")
    if m.get("collided"):
        other = m.get("collision_vehicle")
        verdict = "ego collision" + (f" with {name(other)}" if other is not None else "")
        if m.get("collision_time") is not None:
            verdict += f" at {at(m['collision_time'])}"
        others = n_all - 1
    else:
        verdict = "no ego collision"
        others = n_all
    if others > 0:
        verdict += f"; {others} collision(s) between other road users"
    first = ("collided", "collision_time", "collision_vehicle", "delta_v_ego", "relative_speed", "min_distance")
    keys = [k for k in first if k in m] + sorted(k for k in m if k not in first and k != "collisions")
    labels = {"collided": "ego collided", "n_collisions": "collisions in all"}
    rows = [(labels.get(k, k.replace("_", " ")) + (f" ({SIM_UNITS[k]})" if k in SIM_UNITS else ""), m[k]) for k in keys]
    body = f'<p class="verdict">{esc(verdict)}</p>' + table(rows)
    if collisions:
        items = []
        for c in collisions:
            pair = " and ".join(name(i) for i in c.get("vehicles", []))
            dv = ", ".join(
                f"{'ego' if int(k) == ego else 'agent ' + str(k)} {fmt(v)}"
                for k, v in (c.get("delta_v") or {}).items()
                if v is not None
            )
            items.append(
                f"<li>{esc(pair)} at {esc(at(c.get('time', float('nan'))))}, relative speed "
                f"{esc(fmt(c.get('relative_speed')))} m/s" + (f", delta-v {esc(dv)} m/s" if dv else "") + "</li>"
            )
        body += "<h3>Every collision in the simulation</h3><ol>" + "".join(items) + "</ol>"
    return Section(title, body)


def _search_columns(df: Any) -> Any:
    cols = {c.lower(): c for c in df.columns}
    ren = {}
    for want, aliases in (("dx", ("dx", "d_lon")), ("dy", ("dy", "d_lat"))):
        src = next((cols[a] for a in aliases if a in cols), None)
        if src is None:
            raise UserError(f"search table needs a column {want} (or {'/'.join(aliases[1:])}); has {list(df.columns)}")
        ren[src] = want
    for need in ("collided", "robustness"):
        if need not in df.columns:
            raise UserError(f"search table needs a column {need}; has {list(df.columns)}")
    return df.rename(columns=ren)


def search_section(results: Any, title: str = "Search: start positions") -> Section:
    """Start-position map coloured by outcome, with safe-variant counts.

    ``results``: a DataFrame (or a path to a CSV) with columns dx, dy (ego start offset, m;
    ``d_lon``/``d_lat`` accepted), collided (bool) and robustness (m, minimum separation, negative
    on collision). A variant is safe when it does not collide (or per a ``safe`` column if given).
    """
    import pandas as pd

    df = pd.read_csv(results) if isinstance(results, str | Path) else results
    df = _search_columns(df)
    if df.empty:
        return Section(title, "<p>The search table is empty.</p>")
    collided = df["collided"].astype(str).str.lower().isin(["true", "1", "1.0", "yes"]).to_numpy()
    safe = (
        df["safe"].astype(str).str.lower().isin(["true", "1", "1.0", "yes"]).to_numpy()
        if "safe" in df.columns
        else ~collided
    )
    rob = pd.to_numeric(df["robustness"], errors="coerce").to_numpy(float)
    fig = _figure(8, 5)
    ax = fig.add_subplot()
    from matplotlib.colors import TwoSlopeNorm

    finite = rob[np.isfinite(rob)]
    # red below zero (contact), green above: centre the colour scale on zero when it is inside the range
    norm = TwoSlopeNorm(0.0) if finite.size and finite.min() < 0 < finite.max() else None
    sc_plot = ax.scatter(df["dx"], df["dy"], c=rob, cmap="RdYlGn", norm=norm, s=22, edgecolors="none", zorder=2)
    ax.scatter(df["dx"][collided], df["dy"][collided], marker="x", c="k", s=18, lw=0.8, zorder=3, label="collided")
    ax.scatter([0], [0], marker="*", c="#d32f2f", s=120, zorder=4, label="original start")
    fig.colorbar(sc_plot, ax=ax, label="robustness (m)")
    ax.set_xlabel("start offset, longitudinal dx (m)")
    ax.set_ylabel("start offset, lateral dy (m)")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    rows: list[tuple[str, Any]] = [
        ("variants simulated", len(df)),
        ("safe variants", int(safe.sum())),
        ("collided variants", int(collided.sum())),
        ("safe share", float(safe.mean())),
        (
            "robustness min / median / max (m)",
            "-" if not finite.size else f"{finite.min():.2f} / {np.median(finite):.2f} / {finite.max():.2f}",
        ),
    ]
    return Section(title, table(rows) + img(figure_png(fig), "start-position map coloured by outcome"))


def plausibility_section(sc: Scenario) -> Section:
    """Whether each vehicle moves as a vehicle can (:mod:`deepcrashtest.eval.plausibility`) where the video saw it:
    one line for the scenario and a row for each vehicle that turns half round, turns beyond its steering limit on
    more than 5 % of its steps, changes speed faster than its traction allows or slides on more than a fifth of its
    moving samples (a replay and an export show all four)."""
    from deepcrashtest.eval import plausibility as pl

    counts = pl.per_vehicle(sc)
    summary = pl.plausibility(sc, counts)
    rows = []
    for v, p in counts:
        sliding = p["sliding"] / p["moving"] if p["moving"] else 0.0
        if p["half_turns"] or p["over_turning"] > 0.05 * p["steps"] or p["over_traction"] or sliding > 0.2:
            rows.append(
                f"<tr><td>{esc(who(sc, v.id))}</td><td>{p['half_turns']}</td><td>{p['over_turning']} of {p['steps']}"
                f"</td><td>{p['over_traction']} of {p['steps']}</td><td>{p['sliding']} of {p['moving']}</td></tr>"
            )
    line = (
        f"{summary['vehicles']} vehicles, their observed samples: {summary['half_turns']} half turns between two "
        f"samples, {summary['over_turning']} of {summary['steps']} steps turning beyond the steering limit, "
        f"{summary['over_traction']} changing speed faster than the vehicle's acceleration or braking, "
        f"{summary['sliding']} of {summary['moving']} moving samples sliding > "
        f"{pl.SLIDE_MAX_DEG:g} deg off their direction of motion; where the video did not see them (lead-in, "
        f"extrapolation), {summary['unseen_over_turning']} of {summary['unseen_steps']} steps turning beyond the "
        "steering limit."
    )
    if summary["overlapping_pairs"]:
        line += " Passing through each other before the crash: " + ", ".join(
            f"{who(sc, a)} and {who(sc, b)} ({s:g} s)" for a, b, s in summary["overlapping_pairs"]
        )
        line += "."
    if summary["overlapping_on_joining"]:
        line += (
            " Inside each other where the later one joins the scenario (a collision at spawn in other simulators): "
            + ", ".join(
                f"{who(sc, a)} and {who(sc, b)} ({depth:.2f} m at {time_text(sc, t)})"
                for a, b, t, depth in summary["overlapping_on_joining"]
            )
        )
        line += "."
    head = (
        "<tr><th>vehicle</th><th>half turns</th><th>steps beyond the steering limit</th>"
        "<th>steps beyond its traction</th><th>sliding</th></tr>"
    )
    body = f"<p>{esc(line)}</p>" + (
        f'<table class="kv">{head}{"".join(rows)}</table>' if rows else "<p>Every vehicle moves as a vehicle can.</p>"
    )
    return Section("Vehicle plausibility", body + f"<p><small>{esc(summary['rule'])}</small></p>")


def warnings_section(sc: Scenario) -> Section | None:
    if not sc.warnings:
        return None
    return Section("Warnings", "<ul>" + "".join(f"<li>{esc(w)}</li>" for w in sc.warnings) + "</ul>")


def scenario_sections(
    sc: Scenario,
    video: str | Path | None = None,
    sim_metrics: Mapping[str, Any] | Any | None = None,
    search: Any | None = None,
    fidelity: Any | None = None,
    kept: SheetThumbs | None = None,
) -> list[Section]:
    """Every section a scenario (+ optional annotated video, sim metrics, search table, fidelity result) gives.

    ``kept``: the pass's thumbnails of ``video``'s frames (:class:`SheetThumbs`), so the sheet needs no decoding.
    """
    from concurrent.futures import ThreadPoolExecutor

    from deepcrashtest.forking import Forked
    from deepcrashtest.viz.fidelity_section import fidelity_section

    count = kept.count if kept is not None else _frame_count(video) if video is not None else 0
    marks = sheet_marks(sc, count) if video is not None else []
    # two plots drawn in forked children (matplotlib holds the GIL; forked before the sheet's thread starts)
    birdseye, lanes = Forked(birdseye_section, sc), Forked(lane_offset_section, sc)
    with ThreadPoolExecutor(1, thread_name_prefix="contact-sheet") as pool:
        # the sheet (decoding the video without ``kept``: PyAV and OpenCV release the GIL) while matplotlib draws
        sheet = pool.submit(contact_sheet_section, video, sc=sc, kept=kept) if video is not None else None
        motion = motion_section(sc, marks)  # here, while the children draw theirs
        plots = [birdseye.result(), motion, lanes.result()]
    parts: list[Section | None] = [
        overview_section(sc),
        warnings_section(sc),
        source_section(sc),
        camera_section(sc),
        sheet.result() if sheet is not None else None,
        *plots,
        plausibility_section(sc),
        simulation_section(sim_metrics, sc=sc) if sim_metrics is not None else None,
        search_section(search) if search is not None else None,
        fidelity_section(fidelity) if fidelity is not None else None,
    ]
    return [p for p in parts if p is not None]


def _frame_count(video: str | Path) -> int:
    from deepcrashtest.viz.video_frames import VideoFrames

    vf = VideoFrames(video)
    try:
        return vf.frame_count
    finally:
        vf.close()


# --------------------------------------------------------------------------- the file
_CSS = """
body{font:14px/1.45 system-ui,sans-serif;margin:0 auto;max-width:1100px;padding:1em 2em;color:#222}
h1{margin-bottom:0}.meta{color:#666;margin-top:.2em}
h2{border-bottom:1px solid #ccc;padding-bottom:.2em;margin-top:1.6em}
table.kv{border-collapse:collapse}table.kv th{text-align:left;padding:2px 14px 2px 0;color:#555;font-weight:600}
table.kv td{font-family:ui-monospace,monospace;padding:2px 0}img{max-width:100%;display:block;margin:.6em 0}
nav a{margin-right:1em}.verdict{font-size:1.2em;font-weight:bold}
"""


def render_report(sections: Iterable[Section | None], title: str = "DeepCrashTest report") -> str:
    """The report as one HTML string (None sections are skipped)."""
    parts = [s for s in sections if s is not None]
    stamp = datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    nav = "".join(f'<a href="#{s.anchor}">{esc(s.title)}</a>' for s in parts)
    body = "".join(f'<section id="{s.anchor}"><h2>{esc(s.title)}</h2>{s.body}</section>' for s in parts)
    return (
        f'<!doctype html><html lang="en"><head><meta charset="utf-8"><title>{esc(title)}</title>'
        f"<style>{_CSS}</style></head><body><h1>{esc(title)}</h1>"
        f'<p class="meta">deepcrashtest {esc(__version__)}, {stamp}</p><nav>{nav}</nav>{body}</body></html>\n'
    )


def write_report(
    path: str | Path, *sections: Section | None, title: str = "DeepCrashTest report", force: bool = False
) -> Path:
    """Write the sections as one self-contained HTML file, atomically (refuses to overwrite unless ``force``)."""
    return atomic_write_text(path, render_report(sections, title), force=force)


#: Optional files looked for beside a scenario file by :func:`build_report`.
BESIDE_VIDEO = ("annotated.mp4",)
BESIDE_SIM = ("simulation.json",)
BESIDE_SEARCH = ("results.csv", "search/results.csv")
BESIDE_FIDELITY = ("fidelity.json", "fidelity/fidelity.json")


def load_sim_metrics(path: str | Path) -> dict[str, Any]:
    """Metrics from a JSON file: a metrics object, or ``deepcrashtest simulate --json`` output (``metrics`` key;
    its ``collisions`` list is kept under ``collisions``)."""
    from deepcrashtest.fileio import read_json, require_file

    p = require_file(path, "simulation metrics file")
    data = read_json(p)
    m = data.get("metrics", data) if isinstance(data, dict) else data
    if not isinstance(m, dict):
        raise UserError(f"{p}: expected a JSON object of simulation metrics")
    collisions = data.get("collisions") if isinstance(data, dict) else None
    if isinstance(collisions, list) and "collisions" not in m:  # every pair, for the outcome's list
        m = {**m, "collisions": [c for c in collisions if isinstance(c, dict)]}
    return m


def _beside(folder: Path, names: tuple[str, ...]) -> Path | None:
    return next((folder / n for n in names if (folder / n).is_file()), None)


def build_report(
    scenario: str | Path,
    output: str | Path,
    video: str | Path | None = None,
    sim: str | Path | None = None,
    search: str | Path | None = None,
    force: bool = False,
    sim_metrics: Mapping[str, Any] | None = None,
    kept: SheetThumbs | None = None,
) -> dict[str, Any]:
    """Write the report of a scenario file; optional inputs default to the files beside it.

    ``sim_metrics`` (a metrics dict from a run made by the caller) takes the place of ``sim``; ``kept``: the
    thumbnails ``extract`` kept of the annotated video's frames (:class:`SheetThumbs`) for the contact sheet.

    Beside the scenario: ``annotated.mp4`` (contact sheet), ``simulation.json`` (metrics, e.g.
    ``deepcrashtest simulate --json`` output), ``results.csv`` or ``search/results.csv`` (search table).
    """
    from deepcrashtest.fileio import check_writable, require_file

    check_writable(output, force)  # fail before the work, not after
    sc_path = Path(scenario)
    sc = Scenario.load(sc_path)
    folder = sc_path.resolve().parent
    video_p = Path(video) if video is not None else _beside(folder, BESIDE_VIDEO)
    sim_p = Path(sim) if sim is not None else None if sim_metrics is not None else _beside(folder, BESIDE_SIM)
    search_p = Path(search) if search is not None else _beside(folder, BESIDE_SEARCH)
    if video_p is not None:
        require_file(video_p, "video")
    if search_p is not None:
        require_file(search_p, "search table")
    fidelity_p = _beside(folder, BESIDE_FIDELITY)
    from deepcrashtest.viz.fidelity_section import load_fidelity

    sections = scenario_sections(
        sc,
        video=video_p,
        sim_metrics=load_sim_metrics(sim_p) if sim_p is not None else sim_metrics,
        search=search_p,
        fidelity=load_fidelity(fidelity_p) if fidelity_p is not None else None,
        kept=kept if video is None else None,
    )
    path = write_report(output, *sections, title=f"DeepCrashTest report: {sc.name}", force=force)
    return {
        "report": str(path),
        "sections": [s.title for s in sections],
        "video": None if video_p is None else str(video_p),
        "simulation": str(sim_p) if sim_p is not None else "given" if sim_metrics is not None else None,
        "search": None if search_p is None else str(search_p),
        "bytes": path.stat().st_size,
    }


def _rate(source: Any) -> str:
    """The video's frame rate in words: constant, or variable with its mean (``VideoSource.frame_times``)."""
    return f"{source.fps:g} fps" if source.frame_times is None else f"a variable rate, mean {source.fps:.3f} fps"
